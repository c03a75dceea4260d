"""Board clocks whose truth is known: the virtual boards run on them, and benchmarks and tests
compare the daemon's host times with what the clock says the truth was.

``AffineClock``: a fixed offset and skew.  ``DriftClock``: a skew that drifts, and resets (the
board reboots: its clock starts over at 0)."""

from __future__ import annotations

import math
import time


class AffineClock:
    """A board clock whose truth is known: board µs = offset + (1 + skew) * host monotonic µs.

    Benchmarks and tests give a virtual board this clock (``missing-link board --clock-offset-us
    --clock-skew-ppm``) and compare the daemon's host times with :meth:`host_ns`."""

    def __init__(self, offset_us: float, skew_ppm: float) -> None:
        self.offset_us = offset_us
        self.rate = 1.0 + skew_ppm * 1e-6

    def __call__(self) -> int:
        return math.floor(self.offset_us + time.monotonic_ns() * self.rate / 1000.0)

    def host_ns(self, board_us: float) -> float:
        """The CLOCK_MONOTONIC ns at which this clock read ``board_us``."""
        return (board_us - self.offset_us) * 1000.0 / self.rate


class DriftClock:
    """A board clock with offset, skew, a linear drift of the skew, and resets, whose truth is
    known to any process that knows its parameters (the benchmarks' independent check).

    With ``d`` = host µs since ``ref_ns`` (host CLOCK_MONOTONIC), the clock runs at
    ``1 + (skew_ppm + drift_ppm_per_s * d / 1e6) * 1e-6`` board µs per host µs.  Boot 0 starts
    at ``offset_us``; at each ``resets`` time (s after ``ref_ns``) the board resets: its counter
    restarts at 0 at that instant (the boot gap is the server's business: see BoardServer)."""

    def __init__(
        self,
        offset_us: float,
        skew_ppm: float,
        drift_ppm_per_s: float = 0.0,
        ref_ns: int | None = None,
        resets: list[float] | None = None,
    ) -> None:
        self.offset_us = offset_us
        self.skew = skew_ppm * 1e-6
        self.drift = drift_ppm_per_s * 1e-12  # per µs of elapsed time, per µs
        self.ref_ns = time.monotonic_ns() if ref_ns is None else ref_ns
        self.reset_ns = [self.ref_ns + round(s * 1e9) for s in sorted(resets or [])]

    def _f(self, host_ns: float) -> float:
        d = (host_ns - self.ref_ns) / 1000.0
        return d * (1.0 + self.skew) + self.drift * d * d / 2.0

    def boot_at(self, host_ns: float) -> int:
        return sum(1 for r in self.reset_ns if r <= host_ns)

    def _start(self, boot: int) -> tuple[float, float]:
        """(host ns, board µs) where boot ``boot`` starts."""
        if boot == 0:
            return float(self.ref_ns), self.offset_us
        return float(self.reset_ns[boot - 1]), 0.0

    def board_us_at(self, host_ns: float) -> float:
        h0, b0 = self._start(self.boot_at(host_ns))
        return b0 + self._f(host_ns) - self._f(h0)

    def __call__(self) -> int:
        return math.floor(self.board_us_at(time.monotonic_ns()))

    def host_ns(self, board_us: float, boot: int = 0) -> float:
        """The CLOCK_MONOTONIC ns at which boot ``boot`` of this clock read ``board_us``."""
        h0, b0 = self._start(boot)
        h = h0 + (board_us - b0) * 1000.0  # Newton from the nominal rate
        for _ in range(4):
            err = b0 + self._f(h) - self._f(h0) - board_us
            rate = 1.0 + self.skew + self.drift * (h - self.ref_ns) / 1000.0
            h -= err * 1000.0 / rate
        return h
