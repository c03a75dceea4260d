# ruff: noqa: E402, I001  (MicroPython: the modules are found and swapped in before they are imported)
# simtime.ticks_diff and ticks_add (the simulated board's clock, --fast): run(a, b, n) prints
# what the heap grew by over n calls of each (collections off; the results kept in a
# preallocated list), ticks_diff(a, b) and ticks_add(b, ticks_diff(a, b)) (null for -2^29, which
# ticks_add refuses).  Run by simworld.mjs.
import sys

sys.path.append("/lib")
import simworld.simtime as simtime
import gc

OUT = [0, 0]


def run(a, b, n):
    diff = simtime.ticks_diff
    add = simtime.ticks_add
    # ticks_add refuses -2^29, the one difference it cannot be given (as the port's): not added
    adds = diff(a, b) != -simtime.TICKS_HALF
    OUT[1] = None
    gc.collect()
    gc.disable()
    before = gc.mem_alloc()
    for _ in range(n):
        OUT[0] = diff(a, b)
        if adds:
            OUT[1] = add(b, OUT[0])
    grew = gc.mem_alloc() - before
    gc.enable()
    added = "null" if OUT[1] is None else str(OUT[1])
    print('{"grew": %d, "diff": %d, "add": %s}' % (grew, OUT[0], added))
