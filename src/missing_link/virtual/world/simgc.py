"""The `gc` module as the firmware sees it in the simulator (host.mjs puts it in sys.modules as
`gc`): the WebAssembly port's own, with its accounting made a board's.  The MicroPython subset
only.

Theory of operation
-------------------
The npm build of MicroPython (the port's "pyscript" variant) grows its heap on demand
(MICROPY_GC_SPLIT_HEAP_AUTO): gc.mem_free() adds the 128 MiB it could still add (SPLIT), and a
collection only runs when the step returns to node, where nothing on the C stack can hold an
object (ports/webassembly/main.c, py/gc.c in MicroPython 1.27).  With --heap the host stops that
growth (heap.mjs), so the firmware has a board's fixed heap; what the simulator itself holds
(this world, the padding that makes the firmware's share exactly --heap) is BASE, not counted in
mem_alloc(), and the few bytes the padding could not take (SLACK) are not counted free.

In fast mode (simulated time, simtime.py) the heap's work costs a board's time (simcost.py):
gc.mem_free() and gc.mem_alloc() a scan of the heap (`heap_blocks`, a Pico's without --heap);
collect() what the collection will take, charged at the call (so the firmware times its
collections as on a board), from the blocks live after the last one (the host learns the live
blocks after this one and moves the clock on by any difference: fastclock.mjs); `requested`,
`at` and `charged` tell the host.  The live blocks the first charge starts from are those after
the simulator's own modules were loaded, before the firmware (settle(), host.mjs).

With --heap the heap is watched (`watch`, once the firmware has booted): the allocator's
threshold (gc.threshold) is kept here, not in the interpreter, and the heap is looked at at the
end of every step (end_step: a scan of the simulator's own, free): a collection when the bytes
allocated since the last one have reached the threshold (a board's allocator collects at the
allocation that reaches it; this port collects only when a step returns anyway; a board counts
every allocation, freed or not, this what is still allocated: a little later), so the host
knows every collection and what it took.  Each collection's heap is kept for the host too
(used(), live_bytes(): small integers, nothing allocated): the bytes in use as it began, read
at the step's end where it runs, and the bytes live after it.  Between them they say what the
firmware allocated and what it holds, where its own gc.mem_free() readings say where in its
allocation they fell (tests/test_world_beside.py).
"""

import gc as _gc

from . import simcost, simtime

SPLIT = 128 * 1024 * 1024  # gc_get_max_new_split() of the webassembly port
PICO_BLOCKS = 209936 // simcost.BLOCK  # a Pico's heap (docs/hardware.md, "Memory")

BASE = 0  # bytes allocated before the firmware was loaded (the simulator's, the padding)
SLACK = 0  # bytes free beyond the board's heap that the padding could not take (a few blocks)
fast = False  # simulated time (simtime): the heap's work costs a board's time
heap_blocks = PICO_BLOCKS  # the board's heap in blocks (--heap), what a scan and a sweep walk
watch = False  # --heap, fast, booted: allocations charged, the threshold kept here
requested = 0  # collections asked for in this step
at = 0  # where the last one was asked for: simulated µs into the step
charged = 0  # ns the step's request was charged (its estimate)
live = 0  # blocks live after the last collection (watch)
_used = 0  # bytes in use as the last collection began (watch: the step's end)
_since = 0  # bytes allocated right after the last collection
_threshold = -1  # the firmware's gc.threshold while watched (bytes; -1: none)


def watch_heap():
    # --heap, fast: the firmware has booted; from now on the heap is watched (host.mjs)
    global watch, _threshold, _since, live
    _threshold = _gc.threshold()
    _gc.threshold(-1)  # (the interpreter's own: none now; end_step collects instead)
    _since = _gc.mem_alloc()
    live = max(0, _since - BASE) // simcost.BLOCK
    watch = True


def not_the_firmwares(before):
    # The simulator ran code of its own (a test's request: its compilation, its objects) since
    # `before` bytes were allocated: that is not the firmware's towards its threshold (watch)
    global _since
    if watch:
        _since += max(0, _gc.mem_alloc() - before)


def allocated():
    # bytes allocated in the interpreter now (a scan: the simulator's, free)
    return _gc.mem_alloc()


def begin_step():
    global requested, at, charged
    requested = 0
    at = 0
    charged = 0


def end_step():
    # The step's end (watch): the allocator's collection if the firmware's threshold is reached
    # (-> 1).  The scan is the simulator's.
    global _used
    if requested:
        _used = _gc.mem_alloc()  # (the firmware's collection runs as the step returns)
        return 0
    if _threshold <= 0 or not _gc.isenabled():
        return 0
    used = _gc.mem_alloc()
    if used - _since < _threshold:
        return 0
    _used = used
    _gc.collect()  # (runs when the step returns)
    return 1


def settle():
    # After a collection (the step returned): the live blocks, and what it took (ns)
    global live, _since
    _since = _gc.mem_alloc()
    live = max(0, _since - BASE) // simcost.BLOCK
    return simcost.collection_ns(live, heap_blocks)


def used():
    # bytes in use as the last collection began (watch): the live data and the garbage
    return max(0, _used - BASE)


def live_bytes():
    # bytes live after the last collection (watch)
    return max(0, _since - BASE)


def collect():
    global requested, at, charged
    _gc.collect()  # (scheduled: it runs when the step returns)
    requested += 1
    at = simtime.slept()
    if fast:
        charged = simcost.collection_ns(live, heap_blocks)
        simtime.charge_ns(charged)


def mem_free():
    if fast:
        simtime.charge_ns(simcost.scan_ns(heap_blocks))
    return _gc.mem_free() - SPLIT - SLACK


def mem_alloc():
    if fast:
        simtime.charge_ns(simcost.scan_ns(heap_blocks))
    return _gc.mem_alloc() - BASE


def threshold(*amount):
    global _threshold
    if not watch:
        return _gc.threshold(*amount)
    if amount:
        _threshold = amount[0]
        return None
    return _threshold


def enable():
    _gc.enable()


def disable():
    _gc.disable()


def isenabled():
    return _gc.isenabled()
