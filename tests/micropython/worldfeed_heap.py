# ruff: noqa: E402, I001  (MicroPython: the modules are found and swapped in before they are imported)
# worldfeed.steps_at with the simulator's modules as host.mjs --fast has them (simtime.py the
# clock an edge's handler reads): run(n, t0, span) prints what the heap grew by while steps_at
# delivered n edges to an encoder whose handler counts them (collections off; measured on a
# second call, the first having made what stays), the edges counted and the clock each of the
# first, second and last read.  Run by simworld.mjs.
import sys

sys.path.append("/lib")
import simworld.simtime as simtime

sys.modules["time"] = simtime
import simworld.machine

sys.modules["machine"] = simworld.machine
from machine import Pin
from simworld import worldfeed
import gc

worldfeed.clock = simtime
SEEN = [0, 0, 0, 0]  # edges, the first's time, the second's, the last's


def edge(pin):
    k = SEEN[0] + 1
    SEEN[0] = k
    t = simtime.now_us()
    if k < 3:
        SEEN[k] = t
    SEEN[3] = t


Pin(2, Pin.IN).irq(edge)
Pin(3, Pin.IN).irq(edge)


def run(n, t0, span):
    worldfeed.steps_at(2, 3, 1, n, t0, span)
    SEEN[0] = 0
    gc.collect()
    gc.disable()
    before = gc.mem_alloc()
    worldfeed.steps_at(2, 3, 1, n, t0, span)
    grew = gc.mem_alloc() - before
    gc.enable()
    print('{"grew": %d, "seen": [%d, %d, %d, %d]}' % (grew, SEEN[0], SEEN[1], SEEN[2], SEEN[3]))
