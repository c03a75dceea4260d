# Memory on a MicroPython board (docs/hardware.md, "Memory"): the heap's figures for the host,
# and garbage collection kept off the instants the board must be on time for.
#
# Theory of operation
# -------------------
# MicroPython collects garbage when an allocation finds no room, or (gc.threshold) once so many
# bytes were allocated since the last collection: wherever the firmware happens to be, on an
# aligned measurement's instant too, and a collection of a Pico's heap takes milliseconds.  So
# the firmware collects itself, at the end of a loop turn (poll: Firmware.step), when its
# period has passed since its last collection, and, after each, sets gc.threshold to 3/4 of
# the heap then free (read at the first turn with room for it; the allocator counts from the
# collection on, so the most free read after one lately, as the garbage of the turns between
# is in a late reading: _threshold), so the allocator's own collections come only when the
# firmware found no room for a long while.
#
# The heap's work is done in pieces at the turns' end, each only when the next instant the board
# must be on time for (timing.instant_kept: an aligned measurement on the host-time grid, a
# timed call; none: any time will do) is further away than the longest that piece took so far
# plus MARGIN_US (timing.fits, the rule a paced driver's measurement follows too), else at a
# later turn (the next piece at once while there is room for it, but
# for the figures after a collection):
#   LOW      gc.mem_free() right before the collection: the lowest the heap got since the last
#            one (free only falls between collections but for the allocator's own);
#   COLLECT  gc.collect();
#   FREE     gc.mem_free() after it (a collection that only runs when the turn ends, as under
#            the simulator's WebAssembly port, is done by then): what the live data leave free;
#   ALLOC    gc.mem_alloc(), after one collection a second (FIGURES_US) only: a figure for
#            the host, not for pacing (at a later turn: with what was allocated meanwhile, free
#            and allocated add up to a little more than the heap).
# A heap scan (gc.mem_free, gc.mem_alloc: MicroPython walks the whole allocation table) takes
# milliseconds on a Pico too, as long as a collection's sweep, so each piece needs room of its
# own (on the rig's 10 ms grid a scan and a collection never fit in one window).  A collection
# put off for an instant counts in `deferred`; a piece whose span still reached the instant in
# `overlaps` (a planned one never should: the margin was too thin).  Each is timed with the
# board clock: `longest_us` and `last_us` of the collections, `scan_us` the longest scan.
#
# The period follows the allocation rate, seen at each LOW as the heap used up since the last
# FREE over the time between them: short enough that a quarter of the threshold is allocated
# in it at most, long enough to make a pause worth it (MIN_PERIOD_US to MAX_PERIOD_US: a
# stepper's float maths at a few kHz allocates hundreds of KiB a second).  It shrinks at once
# but grows by an eighth a collection at most: allocation comes in bursts (a stepper's moves),
# and a burst's first collection must not be a quiet spell's period away.  More free now than
# after the last one means the allocator collected meanwhile: the period is halved.
#
# a2jMemory -> [B 1][I free][I free low][I allocated][I collections][I longest us][I last us]
#              [I overlaps][I deferred]     (an AVR board: [B 2] and its stack, firmware/avr)

import struct

from .timing import fits

MIN_PERIOD_US = 10000
MAX_PERIOD_US = 500000
PERIOD_US = 100000  # (until the first two collections have measured the allocation rate)
MIN_THRESHOLD = 4096
#: the allocated bytes (ALLOC: a scan, ~5 ms on a Pico) read after a collection this often at
#: most: read after every one, with the other two scans, they held the rover's collections
#: 35 ms apart (25 now), and the heap used up between two of them reached the allocator's
#: threshold in the soak (70 % of it at most now: docs/hardware.md, "Memory")
FIGURES_US = 1000000
KIND_HEAP = 1
IDLE, LOW, COLLECT, FREE, ALLOC = 0, 1, 2, 3, 4  # the heap's work, in this order


class Memory:
    def __init__(self, runtime, gc):
        self.rt = runtime
        self.gc = gc
        self.period_us = PERIOD_US
        self.collections = 0
        self.longest_us = 0
        self.last_us = 0
        self.scan_us = 0
        self.overlaps = 0
        self.deferred = 0  # turns that wanted a collection and found no room before an instant
        self.free = 0
        self.free_low = None
        self.allocated = 0
        self.threshold = None
        self._best = 0  # the most free after a collection lately (the threshold's base)
        self._freed_at = None  # when `free` was read (the allocation rate's start)
        self._figured = None  # when `allocated` was last read
        self._last = runtime.clock()
        self._work(LOW, None)  # (timed once at boot: what the first windows must hold)
        self._work(COLLECT, None)
        self._step = FREE  # (the figures after it: read at the next turns)
        self._threshold(gc.mem_free())  # (until the figures after it are read)
        runtime.add_function("a2jMemory", self._info)

    def poll(self, now):
        # the loop's idle point: the heap's next pieces of work, if due, as long as there is
        # room for them
        timing = self.rt.timing
        due = None
        while True:
            step = self._step
            if step == IDLE:
                if now - self._last < self.period_us:
                    return
                step = self._step = LOW
            took = self.longest_us if step == COLLECT else self.scan_us
            if due is None and timing is not None:
                due = timing.instant_kept(now)
            if not fits(due, now, took):
                if step == COLLECT:
                    self.deferred += 1
                return
            now = self._work(step, due)
            self._step = IDLE if step == ALLOC else step + 1
            if step == ALLOC:
                self._figured = now
            elif step == FREE and self._figured is not None and now - self._figured < FIGURES_US:
                self._step = IDLE
            if step == COLLECT:
                return  # (the figures after it at the next turn: see FREE)

    def _work(self, step, due):
        gc = self.gc
        clock = self.rt.clock
        free = 0
        t0 = clock()
        if step == COLLECT:
            gc.collect()
        elif step == ALLOC:
            self.allocated = gc.mem_alloc()
        else:
            free = gc.mem_free()
        t1 = clock()
        took = t1 - t0
        if due is not None and t1 >= due:
            self.overlaps += 1
        if step == COLLECT:
            self.collections += 1
            self.last_us = took
            self.longest_us = max(self.longest_us, took)
            self._last = t1
            return t1
        self.scan_us = max(self.scan_us, took)
        if step == LOW:
            if self.free_low is None or free < self.free_low:
                self.free_low = free
            if self._freed_at is not None and self.free:
                self._pace(self.free - free, t0 - self._freed_at)
        elif step == FREE:
            self.free = free
            self._freed_at = t1
            self._threshold(free)
        return t1

    def _pace(self, used, since_us):
        # the next period from the heap used up in `since_us` (less than nothing: the
        # allocator collected meanwhile, so the period was too long)
        if used < 0:
            period = self.period_us // 2
        else:
            period = since_us * (self.threshold // 4) // max(used, 1)
            period = min(period, self.period_us + self.period_us // 8)
        self.period_us = max(MIN_PERIOD_US, min(MAX_PERIOD_US, period))

    def _threshold(self, free):
        # From the most free seen after a collection lately, not this reading alone: one made
        # turns after the collection has their garbage in it (25 KB on the rover when the room
        # for the scan came 20 ms late), where the allocator counts from the collection.  The
        # best decays by 1/32 a reading, so live data that grew are followed within tens.
        self._best = max(free, self._best - self._best // 32)
        self.threshold = max(MIN_THRESHOLD, self._best * 3 // 4)
        self.gc.threshold(self.threshold)

    def _info(self, payload):
        low = self.free if self.free_low is None else self.free_low
        n = [v & 0xFFFFFFFF for v in (self.free, low, self.allocated, self.collections,
             self.longest_us, self.last_us, self.overlaps, self.deferred)]  # fmt: skip
        return 0, struct.pack("<BIIIIIIII", KIND_HEAP, *n)
