"""The clock-sync simulation: clock and link models, the anchor methods, a scenario runner.
Pure, seeded, no I/O (a bench and test harness; it lives with the virtual boards, not in the
core).

Used by ``bench/bench_timesync.py`` and the tests.  Host time is the truth (ns from 0); a board
clock is a function of it; a link turns a send time into an arrival time (or a loss).

Link models (delays in µs; every one also has heavy tails, load bursts and loss):

``pty``    two processes on one machine: ~8-9 µs floor per direction plus exponential jitter,
           a 3 % Pareto tail (scheduling), 0.2-1 s bursts of load every ~20 s, 0.5 % loss.
``usb``    USB full speed, 1 ms frames: the request goes out within the frame (~25 µs), the
           reply's completion is reported at the end of the frame it moved in (UHCI/OHCI
           interrupt-on-complete / done-queue write-back), then host interrupt latency.
``ftdi``   a UART at 921600 Bd behind an FTDI-like bridge with a 1 ms latency timer: bytes take
           10.85 µs each; the bridge hands received bytes to USB on its free-running 1 ms timer
           (its own crystal), and an xHCI-style host completes that transfer at once.
           The host knows the baud rate, so each exchange carries the reply's time on the wire.

Methods (every one sees exchanges drawn from the same link and clock):

``missing-link``  this package's ClockSync with its own probe schedule;
``cristian``      micro-ROS style: one exchange (every 1 s), offset from its midpoint, no skew;
``rosserial``     host stamp of the board's message + the whole round trip, ms resolution,
                  re-synced every 2.5 s, no skew (maps board t3 to host t4);
``px4``           PX4/MAVLink TIMESYNC style: 10 Hz, exchanges with RTT < 10 ms, exponential
                  filter on the midpoint offset plus a skew term, gains 0.05 -> 0.003 over the
                  first 500 exchanges.
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from ..timesync.exchange import Exchange
from ..timesync.sync import ClockSync, SyncOptions
from .sync_links import LINKS, MS, BoardClock, S


# ---- methods -----------------------------------------------------------------------------------
class Method(Protocol):
    name: str

    def due(self) -> float: ...  # host s of the next probe
    def on_exchange(self, ex: Exchange, now: float) -> None: ...
    def on_lost(self, now: float) -> None: ...
    def map(self, board_us: int) -> tuple[float, float | None] | None: ...


class Ours:
    name = "missing-link"

    def __init__(self, options: SyncOptions | None = None) -> None:
        self.sync = ClockSync(options, seed=0)  # the probe dither too: a run is reproducible
        self.sync.start(0.0)

    def due(self) -> float:
        return self.sync.due()

    def on_exchange(self, ex: Exchange, now: float) -> None:
        self.sync.on_exchange(ex, now)

    def on_lost(self, now: float) -> None:
        self.sync.on_lost(now)

    def map(self, board_us: int) -> tuple[float, float | None] | None:
        m = self.sync.map(board_us)
        return None if m is None else (m.host_ns, m.bound_ns)


class _Periodic:
    period = 1.0

    def __init__(self) -> None:
        self._next = 0.0

    def due(self) -> float:
        return self._next

    def on_lost(self, now: float) -> None:
        self._next = now + self.period


class Cristian(_Periodic):
    """micro-ROS style: offset from one exchange's midpoint, no skew, replaced at every sync."""

    name = "cristian"
    period = 1.0

    def __init__(self) -> None:
        super().__init__()
        self.offset: float | None = None

    def on_exchange(self, ex: Exchange, now: float) -> None:
        self.offset = (ex.t1 + ex.t4) / 2 - (ex.t2 + ex.t3) / 2 * 1000
        self._next = now + self.period

    def map(self, board_us: int) -> tuple[float, float | None] | None:
        return None if self.offset is None else (board_us * 1000 + self.offset, None)


class Rosserial(_Periodic):
    """rosserial style: the board's message time is the host's receive stamp (the whole trip
    added), and board time counts in milliseconds; re-synced every 2.5 s, no skew."""

    name = "rosserial"
    period = 2.5

    def __init__(self) -> None:
        super().__init__()
        self.anchor: tuple[float, int] | None = None

    def on_exchange(self, ex: Exchange, now: float) -> None:
        self.anchor = (float(ex.t4), ex.t3 // 1000)
        self._next = now + self.period

    def map(self, board_us: int) -> tuple[float, float | None] | None:
        if self.anchor is None:
            return None
        h, ms = self.anchor
        return h + (board_us // 1000 - ms) * 1e6, None


class Px4(_Periodic):
    """PX4/MAVLink TIMESYNC style filter (offset EMA + skew term, RTT < 10 ms)."""

    name = "px4"
    period = 0.1
    WINDOW = 500

    def __init__(self) -> None:
        super().__init__()
        self.offset: float | None = None
        self.skew = 0.0
        self.n = 0

    def on_exchange(self, ex: Exchange, now: float) -> None:
        self._next = now + self.period
        if ex.rtt_ns >= 10 * MS:
            return
        sample = (ex.t1 + ex.t4) / 2 - (ex.t2 + ex.t3) / 2 * 1000
        if self.offset is None:
            self.offset = sample
        else:
            if self.n < self.WINDOW:
                progress = self.n / self.WINDOW
                p = 1.0 - math.exp(0.5 * (1.0 - 1.0 / (1.0 - progress)))
                gain = p * 0.003 + (1 - p) * 0.05
            else:
                gain = 0.003
            prev = self.offset
            self.offset = gain * sample + (1 - gain) * (self.offset + self.skew)
            self.skew = gain * (self.offset - prev) + (1 - gain) * self.skew
        self.n += 1

    def map(self, board_us: int) -> tuple[float, float | None] | None:
        return None if self.offset is None else (board_us * 1000 + self.offset, None)


METHODS: dict[str, Callable[[], Method]] = {
    "missing-link": Ours,
    "cristian": Cristian,
    "rosserial": Rosserial,
    "px4": Px4,
}


# ---- the scenario runner -----------------------------------------------------------------------
@dataclass
class Result:
    method: str
    link: str
    seed: int
    errors_ns: np.ndarray = field(repr=False)  # after warm-up
    backwards: int  # samples whose host time went below the previous sample's
    covered: float | None  # fraction of samples inside the reported bound (None: no bound)
    first_bound_s: float | None  # first estimate with a bound < 1 ms
    settle_s: float | None  # from then on |error| stays under settle_us
    exchanges: int
    lost: int

    def pct(self, q: float) -> float:
        return float(np.percentile(np.abs(self.errors_ns), q)) / 1000.0


class _Samples:
    """The samples of one run: a sample every ``period`` of host time, mapped by the method when
    it reaches the host (``arrival_lag`` after it was measured), its error and bound tallied."""

    def __init__(
        self,
        clock: BoardClock,
        m: Method,
        srng: random.Random,
        *,
        sample_hz: float,
        duration_s: float,
        warmup_s: float,
        settle_us: float,
    ) -> None:
        self.clock, self.m = clock, m
        self.period = S / sample_hz
        self.t = srng.uniform(0, self.period)
        self.end_ns = duration_s * S
        self.warmup_ns = warmup_s * S
        self.settle_ns = settle_us * 1000
        self.arrival_lag = 1.5 * MS  # samples are mapped when they reach the host
        self.errors: list[float] = []
        self.prev_h: float | None = None
        self.backwards = 0
        self.inside = self.total = 0
        self.last_bad = 0.0
        self.first_bound: float | None = None

    def until(self, t_host: float) -> None:
        """Map every sample that has reached the host by ``t_host`` (ns)."""
        while self.t + self.arrival_lag < t_host and self.t < self.end_ns:
            got = self.m.map(self.clock.us(self.t))
            if got is not None:
                self._tally(*got)
            self.t += self.period

    def _tally(self, h: float, bound: float | None) -> None:
        err = h - self.t
        if self.prev_h is not None and h < self.prev_h:
            self.backwards += 1
        self.prev_h = h
        if bound is not None:
            self.total += 1
            self.inside += abs(err) <= bound
            if self.first_bound is None and bound < 1 * MS:
                self.first_bound = self.t / S
        if abs(err) > self.settle_ns:
            self.last_bad = self.t
        if self.t >= self.warmup_ns:
            self.errors.append(err)


def run(
    method: str,
    link: str,
    seed: int,
    *,
    duration_s: float = 120.0,
    warmup_s: float = 10.0,
    sample_hz: float = 100.0,
    settle_us: float = 50.0,
    timeout_s: float = 0.1,
) -> Result:
    rng = random.Random(f"{seed}:clock")
    clock = BoardClock(rng, duration_s + 1)
    lk = LINKS[link](random.Random(f"{seed}:link"), duration_s + 1)
    m = METHODS[method]()
    samples = _Samples(
        clock,
        m,
        random.Random(f"{seed}:samples"),
        sample_hz=sample_hz,
        duration_s=duration_s,
        warmup_s=warmup_s,
        settle_us=settle_us,
    )
    wake = random.Random(f"{seed}:wake")
    exchanges = lost = 0
    now = 0.0
    while now < duration_s:
        now = max(now, m.due())
        now += wake.uniform(0, 60e-6)  # a sleeping thread wakes up to ~60 µs late
        t1 = now * S
        samples.until(t1)
        if lk.lost():
            lost += 1
            now += timeout_s
            samples.until(now * S)
            m.on_lost(now)
            continue
        arrive = lk.up(t1)
        t2_true = arrive + lk.board_stamp_lag()
        t3_true = t2_true + lk.board_turnaround()
        nbytes = 21 + (lk.rng.random() < 0.1)  # a2jClock reply frame, sometimes one stuffed byte
        t4 = lk.down(t3_true, nbytes)
        ex = Exchange(
            int(t1),
            clock.us(t2_true),
            clock.us(t3_true),
            int(t4),
            down_min_ns=int(nbytes * lk.byte_ns),
            up_min_ns=int(5 * lk.byte_ns),  # the request frame (as the daemon assumes it)
        )
        samples.until(t4)
        now = t4 / S
        m.on_exchange(ex, now)
        exchanges += 1
    samples.until(duration_s * S + samples.arrival_lag + 1)
    s = samples
    return Result(
        method,
        link,
        seed,
        np.array(s.errors),
        s.backwards,
        s.inside / s.total if s.total else None,
        s.first_bound,
        s.last_bad / S,
        exchanges,
        lost,
    )
