"""One ``a2jClock`` exchange: the four stamps of a round trip and the delays known to be in it.
What the host side hands clock sync (pure; no numpy, so opening a board does not load it)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Exchange:
    """One ``a2jClock`` round trip."""

    t1: int  #: host ns (CLOCK_MONOTONIC), just before the request was written
    t2: int  #: board µs, when the request's last byte arrived
    t3: int  #: board µs, just before the reply's first byte
    t4: int  #: host ns, when the reply had been read
    down_min_ns: int = 0  #: delay every reply has after t3 (its bytes on a slow link)
    up_min_ns: int = 0  #: delay every request has between t1 and t2 (its bytes on a slow link)

    @property
    def rtt_ns(self) -> int:
        return self.t4 - self.t1

    @property
    def delay_ns(self) -> float:
        """Round trip minus the board's own time between t2 and t3."""
        return (self.t4 - self.t1) - (self.t3 - self.t2) * 1000.0
