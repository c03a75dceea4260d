"""A recorded board clock, played back (``missing-link replay``).  Pure: clock records in, board
time as a function of host time out; the caller passes ``now`` (a lock keeps the timeline's
one start from racing between boards).

Theory of operation
-------------------
A recording keeps every ``a2jClock`` exchange of a board (``/<board>/clock``, ros/clock.py) with
the daemon's estimate after it.  :class:`ClockModel` makes the recorded clock a function again:

* boots: the board restarted where an exchange's board times went back (or its ``clock.epoch``
  changed at a reconnect); refused exchanges (outliers) are left out;
* per boot, knots (host ns, board µs) at most ``KNOT_NS`` apart: in each stretch the estimate
  with the smallest hard bound (the daemon's map, good to a few µs), else the exchange with the
  shortest round trip (its midpoint).  Between knots the clock is linear, beyond them it goes
  on at the nearest stretch's rate: offset, skew and drift as recorded;
* a boot begins where its clock, run backwards, reads 0 (a counter restarts at boot), within
  the gap between the two boots' exchanges.

:class:`Timeline` maps the replay's CLOCK_MONOTONIC to the recording's host time: it starts
``lead_s`` after the first request any replayed board hears (the hosts connect and sync first),
runs ``rate`` times as fast, and with ``loop`` starts the recording again after its end (a pass;
each pass is a new boot of every board).  At ``rate`` other than 1 a board's times are pressed
towards the boot's start (``Clock.board``): a clock that ran ten times too fast would be
outside any crystal's range, and the host's clock sync would rightly refuse it.
"""

from __future__ import annotations

import bisect
import math
import threading
from collections.abc import Sequence
from dataclasses import dataclass, field

from ..ros.clock import REFUSED, ClockRecord

KNOT_NS = 2_000_000_000  #: at most this far apart (host ns) in a boot
MAX_SKEW = 0.01  #: a stretch whose rate is off by more than this is taken at the nominal rate
NOMINAL = 1e-3  #: board µs per host ns


@dataclass
class Boot:
    epoch: str
    start_h: float  #: host ns (CLOCK_REALTIME) from which this boot's clock holds
    knots_h: list[float] = field(default_factory=list)
    knots_b: list[float] = field(default_factory=list)
    slope: float = NOMINAL  #: board µs per host ns where only one knot is known

    def board_at(self, h: float) -> float:
        kh, kb = self.knots_h, self.knots_b
        if len(kh) == 1:
            return kb[0] + (h - kh[0]) * self.slope
        i = min(max(bisect.bisect_right(kh, h) - 1, 0), len(kh) - 2)
        return kb[i] + (h - kh[i]) * (kb[i + 1] - kb[i]) / (kh[i + 1] - kh[i])

    def host_at(self, b: float) -> float:
        kh, kb = self.knots_h, self.knots_b
        if len(kh) == 1:
            return kh[0] + (b - kb[0]) / self.slope
        i = min(max(bisect.bisect_right(kb, b) - 1, 0), len(kb) - 2)
        return kh[i] + (b - kb[i]) * (kh[i + 1] - kh[i]) / (kb[i + 1] - kb[i])


class ClockModel:
    def __init__(self, boots: list[Boot]) -> None:
        assert boots, "a clock model needs a boot"
        self.boots = boots
        self._starts = [b.start_h for b in boots]

    @classmethod
    def from_records(
        cls, records: Sequence[ClockRecord], anchor: tuple[int, int], epoch: str = ""
    ) -> ClockModel:
        """The clock of ``records`` (in recorded order); ``anchor`` (host ns, board µs) is used
        when there are none (a board without ``a2jClock``): the nominal rate through it."""
        knots = ClockKnots()
        for r in records:
            knots.add(r)
        return knots.model(anchor, epoch)

    def boot_at(self, h: float) -> int:
        return max(0, bisect.bisect_right(self._starts, h) - 1)

    def board_at(self, h: float) -> float:
        return self.boots[self.boot_at(h)].board_at(h)


class _Stretches:
    """One boot's exchanges as they come: per stretch of ``KNOT_NS`` the best estimate, else
    the fastest exchange's midpoint (its quality, host ns, board µs)."""

    def __init__(self, r: ClockRecord) -> None:
        self.epoch, self.first_t1, self.last_t4 = r.clock_epoch, r.t1_ns, r.t4_ns
        self.best: dict[int, tuple[float, float, float]] = {}
        self.skew = 0.0

    def add(self, r: ClockRecord, room: bool) -> bool:
        """Take ``r``; False when it would be a stretch more and there is no ``room``."""
        k = (r.t4_ns - self.first_t1) // KNOT_NS
        if k not in self.best and not room:
            return False
        if r.bound_ns >= 0 and r.host_ns:
            best = (r.bound_ns, float(r.host_ns), float(r.board_us))
        else:  # no estimate: the midpoint, good to half the round trip
            rtt = (r.t4_ns - r.t1_ns) - 1000.0 * (r.t3_us - r.t2_us)
            best = (1e12 + rtt, (r.t1_ns + r.t4_ns) / 2.0, (r.t2_us + r.t3_us) / 2.0)
        if k not in self.best or best[0] < self.best[k][0]:
            self.best[k] = best
        self.last_t4 = r.t4_ns
        self.skew = r.skew_ppm if math.isfinite(r.skew_ppm) else 0.0
        return True

    def boot(self) -> Boot:
        """The boot's knots, kept only where both times go forward at a plausible rate."""
        kh: list[float] = []
        kb: list[float] = []
        for _k, (_q, h, b) in sorted(self.best.items()):
            # (knots close together would make a rate of their few µs of error)
            if kh and not (
                h - kh[-1] >= KNOT_NS / 2
                and abs((b - kb[-1]) / (h - kh[-1]) / NOMINAL - 1) < MAX_SKEW
            ):
                continue
            kh.append(h)
            kb.append(b)
        skew = self.skew
        slope = NOMINAL * (1 + skew * 1e-6) if abs(skew) < MAX_SKEW * 1e6 else NOMINAL
        return Boot(self.epoch, -math.inf, kh, kb, slope)


class ClockKnots:
    """A recorded clock read record by record (``add``), keeping only what its model needs:
    per boot a knot per ``KNOT_NS`` stretch, at most ``MAX_KNOTS`` in all (a day and more of
    them; what would be more is left out and counted), so a recording of any length, or one
    crafted of nothing but clock records, costs bounded memory (issue 43.10)."""

    MAX_KNOTS = 100_000

    def __init__(self) -> None:
        self.boots: list[_Stretches] = []
        self.knots = 0
        self.left_out = 0  #: exchanges beyond MAX_KNOTS, not used
        self._last_t3 = -1

    def add(self, r: ClockRecord) -> None:
        if r.result == REFUSED or r.t4_ns < r.t1_ns or r.t3_us < r.t2_us:
            return
        boots = self.boots
        room = self.knots < self.MAX_KNOTS
        if not boots or r.t2_us < self._last_t3 or r.clock_epoch != boots[-1].epoch:
            if not room:
                self.left_out += 1
                return
            boots.append(_Stretches(r))
        before = len(boots[-1].best)
        if not boots[-1].add(r, room):
            self.left_out += 1
            return
        self.knots += len(boots[-1].best) - before
        self._last_t3 = r.t3_us

    def model(self, anchor: tuple[int, int], epoch: str = "") -> ClockModel:
        """The clock; ``anchor`` (host ns, board µs) when no exchange was kept."""
        if not self.boots:
            return ClockModel([Boot(epoch, -math.inf, [float(anchor[0])], [float(anchor[1])])])
        boots = [s.boot() for s in self.boots]
        boots[0].start_h = -math.inf
        for k in range(1, len(boots)):
            lo, hi = float(self.boots[k - 1].last_t4), float(self.boots[k].first_t1)
            zero = boots[k].host_at(0.0)
            boots[k].start_h = min(max(zero, lo), hi) if lo <= hi else hi
        return ClockModel(boots)


class Timeline:
    """The replay's monotonic time -> (pass, the recording's host time)."""

    GAP_NS = 1_000_000_000  #: recording time between the end of a pass and the next (loop)

    def __init__(
        self, first_ns: int, end_ns: int, rate: float, lead_s: float, loop: bool, now_ns: int
    ) -> None:
        self.first = first_ns
        self.length = max(1, end_ns - first_ns) + self.GAP_NS
        self.rate = rate
        self.lead_ns = round(lead_s * 1e9)
        self.loop = loop
        self.m0 = now_ns + self.lead_ns  # until started: the clock is not read by any host
        self.started = False
        self._lock = threading.Lock()  # (every board's thread may be the first to start it)

    def start(self, now_ns: int) -> None:
        """The first request from a host: the recording starts ``lead_s`` after it."""
        with self._lock:
            if not self.started:
                self.m0 = now_ns + self.lead_ns
                self.started = True

    def at(self, now_ns: int) -> tuple[int, float]:
        """(pass, recording host ns) at replay monotonic ``now_ns``."""
        span = (now_ns - self.m0) * self.rate
        k = int(span // self.length) if self.loop and span > 0 else 0
        return k, self.first + span - k * self.length

    def mono_at(self, k: int, h: float) -> float:
        """The replay monotonic ns at which pass ``k`` reaches recording time ``h``."""
        return self.m0 + (h - self.first + k * self.length) / self.rate


class Clock:
    """One replayed board's clock: the recorded one, on the timeline, pressed by ``rate``."""

    def __init__(self, model: ClockModel, timeline: Timeline) -> None:
        self.model = model
        self.timeline = timeline
        self._anchors = [b.board_at(max(float(timeline.first), b.start_h)) for b in model.boots]

    def board(self, boot: int, b: float) -> int:
        """A recorded board time of ``boot`` as this replay's board tells it."""
        rate = self.timeline.rate
        if rate != 1.0:
            a = self._anchors[boot]
            b = a + (b - a) / rate
        return max(0, math.floor(b))

    def read(self, now_ns: int) -> tuple[int, int, int]:
        """(pass, boot, board µs) at replay monotonic ``now_ns``."""
        k, h = self.timeline.at(now_ns)
        boot = self.model.boot_at(h)
        return k, boot, self.board(boot, self.model.boots[boot].board_at(h))

    def epoch(self, k: int, boot: int) -> str:
        """The board's ``clock.epoch`` in pass ``k``, boot ``boot``: as recorded where a boot
        said its own, otherwise a new one (a boot the recording saw only through a reset)."""
        b = self.model.boots
        own = b[boot].epoch if boot == 0 or b[boot].epoch != b[boot - 1].epoch else ""
        name = own or f"{b[boot].epoch}+{boot}"
        return name if k == 0 else f"{name}.{k}"
