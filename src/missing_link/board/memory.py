# Memory on a MicroPython board (docs/hardware.md, "Memory"): the heap's figures for the host,
# and garbage collection kept off the instants the board must be on time for.
#
# Theory of operation
# -------------------
# MicroPython collects garbage when an allocation finds no room, or (gc.threshold) once so many
# bytes were allocated since the last collection: wherever the firmware happens to be, on an
# aligned measurement's instant too, and a collection of a Pico's heap takes milliseconds.  So
# the firmware collects itself, at the end of a loop turn (poll: Firmware.step), when
#   - its period has passed since its last collection, and
#   - the next instant it must be on time for (timing.next_instant: an aligned measurement on
#     the host-time grid, a timed call; none: any time will do) is further away than the
#     longest collection so far plus MARGIN_US; otherwise it waits for room (`deferred`),
# and, after each, sets gc.threshold to 3/4 of the heap then free, so the allocator's own
# collections come only when the firmware found no room for a long while.  The period follows
# the allocation rate, seen at each collection as the heap used up since the last one (free
# after it, less free now) over the time between them: short enough that a quarter of the
# threshold is allocated in it at most, long enough to make a pause worth it (MIN_PERIOD_US to
# MAX_PERIOD_US: a stepper's float maths at a few kHz allocates hundreds of KiB a second).  More
# free now than after the last one means the allocator collected meanwhile: the period is
# halved.
# Each collection is timed with the board clock, with the heap scan before it (the span the loop
# is busy): the longest and the last.  One whose span reached the instant counts in `overlaps`
# (a planned one never should: the margin was too thin).  Right before a collection,
# gc.mem_free() is the lowest the heap got since the last one (free only falls between
# collections but for the allocator's own): the low point.  What the live data leave free is
# read at the next turn's idle point (a collection that only runs when the turn ends, as under
# the simulator's WebAssembly port, is done by then; on a board the turn's own allocations are
# in it).  The heap scans (gc.mem_free, gc.mem_alloc) cost time too, so only then.
#
# a2jMemory -> [B 1][I free][I free low][I allocated][I collections][I longest us][I last us]
#              [I overlaps][I deferred]     (an AVR board: [B 2] and its stack, firmware/avr)

import struct

MIN_PERIOD_US = 10000
MAX_PERIOD_US = 500000
PERIOD_US = 100000  # (until the first two collections have measured the allocation rate)
MARGIN_US = 2000
MIN_THRESHOLD = 4096
KIND_HEAP = 1


class Memory:
    def __init__(self, runtime, gc):
        self.rt = runtime
        self.gc = gc
        self.period_us = PERIOD_US
        self.collections = 0
        self.longest_us = 0
        self.last_us = 0
        self.overlaps = 0
        self.deferred = 0  # turns that wanted a collection and found no room before an instant
        self.free = 0
        self.free_low = None
        self.allocated = 0
        self.threshold = None
        self._after = False  # a collection was made: the heap's figures are read next turn
        self._start = None  # when the last collection began (the allocation rate's time)
        now = runtime.clock()
        self._last = now
        self.collect(now, None)  # (timed once at boot: what the first window must hold)
        self._threshold(gc.mem_free())  # (until the figures after it are read)
        runtime.add_function("a2jMemory", self._info)

    def poll(self, now):
        # the loop's idle point: a collection now if it is due and there is room for it
        if self._after:
            self._read()
        if now - self._last < self.period_us:
            return
        timing = self.rt.timing
        due = timing.next_instant(now) if timing is not None else None
        if due is not None and due - now <= self.longest_us + MARGIN_US:
            self.deferred += 1
            return
        self.collect(now, due)

    def collect(self, now, due):
        gc = self.gc
        clock = self.rt.clock
        t0 = clock()
        free = gc.mem_free()
        if self.free_low is None or free < self.free_low:
            self.free_low = free
        if self._start is not None and self.free:
            self._pace(self.free - free, t0 - self._start)
        gc.collect()
        t1 = clock()
        took = t1 - t0
        self.collections += 1
        self.last_us = took
        if took > self.longest_us:
            self.longest_us = took
        if due is not None and t1 >= due:
            self.overlaps += 1
        self._start = t0
        self._last = t1
        self._after = True

    def _read(self):
        gc = self.gc
        self._after = False
        self.free = gc.mem_free()
        self.allocated = gc.mem_alloc()
        self._threshold(self.free)

    def _pace(self, used, since_us):
        # the next period from the heap used up in `since_us` (less than nothing: the
        # allocator collected meanwhile, so the period was too long)
        if used < 0:
            period = self.period_us // 2
        else:
            period = since_us * (self.threshold // 4) // max(used, 1)
        self.period_us = max(MIN_PERIOD_US, min(MAX_PERIOD_US, period))

    def _threshold(self, free):
        self.threshold = max(MIN_THRESHOLD, free * 3 // 4)
        self.gc.threshold(self.threshold)

    def _info(self, payload):
        low = self.free if self.free_low is None else self.free_low
        n = [v & 0xFFFFFFFF for v in (self.free, low, self.allocated, self.collections,
             self.longest_us, self.last_us, self.overlaps, self.deferred)]  # fmt: skip
        return 0, struct.pack("<BIIIIIIII", KIND_HEAP, *n)
