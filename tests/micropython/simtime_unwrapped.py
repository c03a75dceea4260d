# ruff: noqa: E402, I001  (MicroPython: the modules are found and swapped in before they are imported)
# simtime's ticks_ms and time() past the wrap of its µs (2^30 µs, 17.9 minutes): run(steps, us)
# moves the clock as the host does (set_now at each step's start, then the step's sleep of `us`)
# `steps` times from 0, then prints ticks_us, ticks_ms, time() and what the heap grew by over
# a thousand reads of each and steps of the clock (collections off).  Run by simworld.mjs.
import sys

sys.path.append("/lib")
import simworld.simtime as simtime
import gc

OUT = [0, 0, 0]


def run(steps, us):
    # (each case from a fresh clock at 0, as the host's starts: the module's state put back)
    simtime._now = simtime._ms = simtime._sub = simtime._s = simtime._ms_in_s = 0
    for _ in range(steps):
        simtime.set_now(simtime.now_us())  # (a step's start: where the last one left it)
        simtime.sleep_us(us)
    simtime.free = True
    gc.collect()
    gc.disable()
    before = gc.mem_alloc()
    for _ in range(1000):
        simtime.set_now(simtime.now_us(), 5)
        simtime.advance(997)
        OUT[0] = simtime.ticks_us()
        OUT[1] = simtime.ticks_ms()
        OUT[2] = simtime.time()
    grew = gc.mem_alloc() - before
    gc.enable()
    print('{"us": %d, "ms": %d, "s": %d, "grew": %d}' % (OUT[0], OUT[1], OUT[2], grew))
