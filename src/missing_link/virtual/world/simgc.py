"""The `gc` module as the firmware sees it in the simulator (host.mjs puts it in sys.modules as
`gc`): the WebAssembly port's own, with its accounting made a board's.  The MicroPython subset
only.

The npm build of MicroPython (the port's "pyscript" variant) grows its heap on demand
(MICROPY_GC_SPLIT_HEAP_AUTO): gc.mem_free() adds the 128 MiB it could still add (SPLIT), and a
collection only runs when the step returns to node, where nothing on the C stack can hold an
object (ports/webassembly/main.c, py/gc.c in MicroPython 1.27).  With --heap the host stops that
growth (host.mjs), so the firmware has a board's fixed heap; what the simulator itself holds
(this world, the padding that makes the firmware's share exactly --heap) is BASE, not counted in
mem_alloc(), and the few bytes the padding could not take (SLACK) are not counted free.
collect() schedules the collection and, in fast mode, advances the simulated clock by what the
last one took (the host measures each, after the step: fastclock.mjs), so the firmware times
its collections as it does on a board; `requested` tells the host the step asked.
"""

import gc as _gc

from . import simtime

SPLIT = 128 * 1024 * 1024  # gc_get_max_new_split() of the webassembly port

BASE = 0  # bytes allocated before the firmware was loaded (the simulator's, the padding)
SLACK = 0  # bytes free beyond the board's heap that the padding could not take (a few blocks)
fast = False  # simulated time (simtime): collect() costs what the last collection took
last_us = 0  # what the last collection took, simulated µs (the host measures it)
requested = 0  # collections asked for in this step
at = 0  # where the last one was asked for: simulated µs into the step


def collect():
    global requested, at
    _gc.collect()  # (scheduled: it runs when the step returns)
    requested += 1
    at = simtime.slept()
    if fast:
        simtime.advance(last_us)


def mem_free():
    return _gc.mem_free() - SPLIT - SLACK


def mem_alloc():
    return _gc.mem_alloc() - BASE


def threshold(*amount):
    return _gc.threshold(*amount)


def enable():
    _gc.enable()


def disable():
    _gc.disable()


def isenabled():
    return _gc.isenabled()
