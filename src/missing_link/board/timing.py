# Acting on host time (docs/timesync.md, "Measuring together, acting on time"): the host's map
# of this board's clock (a2jHostMap), the sampling grid of aligned transducers, and timed calls.
#
# Theory of operation
# -------------------
# The daemon hands the board its current estimate of the map board µs -> host ns (CLOCK_REALTIME,
# the time base samples are published in) after every clock exchange.  A map vouches for board
# times within MAP_LIFE_US of its reference: beyond, the board's crystal may have wandered more
# than the estimate knows.  With a valid map:
#
# * aligned sampling: a transducer with `aligned` samples at the host instants k * P + phase * P
#   (P = 1 / rate_hz, counted in host ns since the epoch), so every board with the same rate
#   samples at the same instants; the driver asks `next_grid(period_us, phase, now)` for the
#   board tick of the next one.  Without a valid map it runs free and each such sample is
#   counted (`unaligned`): never silently misaligned.
# * timed calls: a2jAt [q host ns][B function index][payload] calls that function at the tick
#   the host time maps to (reply: 0 + [Q board tick]), or refuses when the time is past, when
#   it lies beyond what the map vouches for, or when no map is there.  Only an actuator's
#   command (a function a transducer's `call=` names) or a2jGoodbye (a host that means to stop
#   at a time) can be timed: anything else - a2jAt itself, a2jMany, a reader whose reply would
#   go nowhere - is refused when asked (NOT_TIMEABLE), the same on AVR (timing.c).  The queue
#   holds at most QUEUE entries.  The shell asks `next_precise_us()` to be on time (the
#   MicroPython firmware stops sleeping for the last stretch).  While a call runs,
#   `acting_tick` is the tick it was due at: a driver that models a timer-compare output (the
#   virtual boards' trigger) acts at that tick, however late the process got round to it.
# * a queued call is a command the host gave and the board has not yet carried out: when the
#   host is gone it must not be carried out at all.  cancel() drops the whole queue, counted
#   (`cancelled`) and said in a2jDebug and the log (WARN); the failsafe (failsafe.py) calls it
#   on a2jGoodbye, and when the host has been silent (no intact frame) for the board's shortest
#   failsafe_ms: then for the calls due after that moment (one due until then, the host still
#   there, runs, if late).  A timed call that raises is said once (ERROR) and counted; one
#   its function refuses when due (not 0: a transducer disabled meanwhile, a value it does not
#   take) is counted as refused, not done, and said in the log (WARN).
# * next_instant(now): the soonest board tick the board must be on time for (a timed call, or an
#   aligned transducer's next grid instant; its measurement if that is due already), so that
#   the firmware can keep its own pauses off it.  The firmware's own work (a garbage
#   collection: memory.py; a free-running driver's measurement: pacing.py) follows one rule,
#   fits(): it starts only when that instant is further away than the longest it took plus
#   MARGIN_US; both ask instant_kept(now), next_instant kept while it is ahead and nothing
#   changed it (no request since, no timed call dropped).
#
# a2jAlignInfo -> [B map valid][I map age ms][I unaligned samples][I timed calls done]
#                 [I timed calls refused, when asked or when due][I measurements deferred]
#                 [I polls that reached an instant] (the last two: pacing.py; an AVR board
#                 answers without them): what the daemon shows.
#
# Integer maths only (MicroPython's floats may be 32 bit; its ints are arbitrary precision).

import struct

from .log import ERROR, RAISED_TIMED, SOURCE_BOARD, WARN

MAP_LIFE_US = 10000000
#: beyond the longest the firmware's own work took (a collection, a heap scan: memory.py; a
#: driver's measuring poll: pacing.py): its length moves little from one to the next, and the
#: turn after it must start before the instant (a turn's own work, ~0.3 ms on a Pico); 2 ms
#: left the thesis rig's 100 Hz grid no room at all
MARGIN_US = 1000
QUEUE = 8
_BILLION = 1000000000
_MILLION = 1000000
NOT_TIMEABLE = b"only an actuator's call or a2jGoodbye can be timed"


class Timing:
    def __init__(self, runtime):
        self.rt = runtime
        self.unaligned = 0
        self.done = 0
        self.refused = 0
        self.cancelled = 0  # queued calls dropped: the host said goodbye or went silent
        self._queue = []  # (board tick, handler, payload, name), soonest first
        self.acting_tick = None  # while a timed call runs: the tick it was due at
        self.calls = None  # the actuators' commands a2jAt takes (None: the transducers' call=)
        self._kept = None  # the next instant, as last looked for (instant_kept)
        self._requests = -1  # ... with the runtime's count of requests then
        runtime.add_function("a2jAt", self._at)
        runtime.add_function("a2jAlignInfo", self._info)

    # ---- the map ------------------------------------------------------------------------------
    def map_valid(self, now):
        m = self.rt.host_map
        return m is not None and -MAP_LIFE_US <= now - m[0] <= MAP_LIFE_US

    def host_at(self, board_us):
        b0, h0, ppb = self.rt.host_map
        return h0 + ((board_us - b0) * (_BILLION + ppb)) // _MILLION

    def next_grid(self, period_us, phase, now):
        # The board tick of the first grid instant after `now` (None: no valid map).
        if not self.map_valid(now):
            return None
        p = period_us * 1000
        offset = int(phase * p) % p
        h = self.host_at(now)
        k = (h - offset) // p + 1
        return self.rt.board_time_at(k * p + offset)

    def next_instant(self, now):
        # The soonest tick the board must be on time for (None: none): a timed call, or an
        # aligned measurement (a driver that samples on the grid: its next instant after `now`,
        # or the one it has not measured yet).
        due = self.next_precise_us()
        if not self.map_valid(now):
            return due
        for t in self.rt.transducers:
            drv = t.driver
            if not t.enabled or not getattr(drv, "aligned", False):
                continue
            at = self.next_grid(drv.period_us, drv.phase, now)
            pending = drv.next_due_us()
            if pending is not None and (at is None or pending < at):
                at = pending
            if at is not None and (due is None or at < due):
                due = at
        return due

    def instant_kept(self, now):
        # next_instant(now), kept while it is ahead and no request came (a new map, a rate, a
        # timed call: rt.calls) nor a timed call was dropped: its grid maths make big integers
        # of host ns, garbage that, asked at every turn with work to place, brought the
        # allocator's own collections onto the rover's grid
        kept = self._kept
        if kept is None or kept <= now or self._requests != self.rt.calls:
            kept = self._kept = self.next_instant(now)
            self._requests = self.rt.calls
        return kept

    # ---- timed calls ----------------------------------------------------------------------------
    def _at(self, payload):
        if len(payload) < 9:
            return 0xFF, b"expects [q host ns][B function index][payload]"
        host_ns = struct.unpack("<q", payload[:8])[0]
        index = payload[8]
        rt = self.rt
        now = rt.clock()
        if not self._timeable(index):
            self.refused += 1
            return 0xFF, NOT_TIMEABLE
        if not self.map_valid(now):
            self.refused += 1
            return 0xFF, b"no valid host map (a2jHostMap)"
        tick = rt.board_time_at(host_ns)
        if tick < now:
            self.refused += 1
            return 0xFF, ("past by %d us" % (now - tick)).encode()
        if tick - rt.host_map[0] > MAP_LIFE_US:
            self.refused += 1
            return 0xFF, (
                "%d ms ahead: beyond what the map vouches for (%d ms)"
                % ((tick - now) // 1000, MAP_LIFE_US // 1000)
            ).encode()
        if len(self._queue) >= QUEUE:
            self.refused += 1
            return 0xFF, b"timed calls queue full"
        name, _kind, handler = rt.functions[index]
        self._queue.append((tick, handler, payload[9:], name))
        self._queue.sort(key=_first)
        return 0, struct.pack("<Q", tick)

    def _timeable(self, index):
        # an actuator's command (a transducer's call=) or a2jGoodbye: a2jAt of a2jAt, a2jMany
        # or a reader is refused (the AVR once ran them into a 16-byte buffer, or address 0)
        rt = self.rt
        if index >= len(rt.functions) or rt.functions[index][1] != 0:
            return False
        name = rt.functions[index][0]
        if name == "a2jGoodbye" or (self.calls is not None and name in self.calls):
            return True
        for t in rt.transducers:
            if t.options.get("call") == name:
                return True
        return False

    def pending(self):
        return len(self._queue)

    def cancel(self, why, after=-1):
        # Drop the queued calls due after board µs `after` (all by default): the host that asked
        # for them is gone (since `after`).  Counted, said once.
        keep = [e for e in self._queue if e[0] <= after]
        n = len(self._queue) - len(keep)
        if n:
            self._queue = keep
            self._kept = None  # (the instant kept may have been one of them)
            self.cancelled += n
            text = "%d timed call%s dropped (%s)" % (n, "" if n == 1 else "s", why)
            self.rt.debug("timing: %s;" % text)
            self.rt.log.line(WARN, text)
        return n

    def next_precise_us(self):
        return self._queue[0][0] if self._queue else None

    def poll(self, now):
        # (self._queue read afresh each time: a timed a2jGoodbye empties it on its way)
        while self._queue and self._queue[0][0] <= now:
            tick, handler, payload, name = self._queue.pop(0)
            self.acting_tick = tick
            try:
                if handler(payload)[0] == 0:
                    self.done += 1
                else:  # refused when due: not done, and said
                    self.refused += 1
                    self.rt.log.line(WARN, "a timed call refused when due: %s" % name)
            except Exception as e:  # noqa: BLE001 - a failing action must not stop the board
                self.rt.debug("timed call: %s;" % e)
                text = "a timed call raised %s: %s" % (type(e).__name__, e)
                self.rt.log.fault(SOURCE_BOARD, RAISED_TIMED, text, ERROR)  # said once, counted
            finally:
                self.acting_tick = None

    def _info(self, payload):
        now = self.rt.clock()
        valid = self.map_valid(now)
        age = (now - self.rt.host_map[0]) // 1000 if self.rt.host_map is not None else 0xFFFFFFFF
        age = max(0, min(age, 0xFFFFFFFF))
        pacing = self.rt.pacing
        n = [v & 0xFFFFFFFF for v in (self.unaligned, self.done, self.refused, pacing.deferred,
             pacing.overlaps)]  # fmt: skip
        return 0, struct.pack("<BIIIIII", 1 if valid else 0, age, *n)


def fits(instant, now, took):
    # The room rule of the firmware's own work (memory.py, pacing.py): work whose longest is
    # `took` µs may start at `now` before `instant` (None: none, any time will do) only when
    # that is further away than `took` and MARGIN_US.
    return instant is None or instant - now > took + MARGIN_US


def _first(item):
    return item[0]
