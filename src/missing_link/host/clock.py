"""The host side's clock, passed in (trio's ``MockClock`` is the model): the system's, or a fake
one whose time stands still until a test advances it.

A link engine (:mod:`.link`), a :class:`~missing_link.host.board.Board` and the shared I/O loop
(:mod:`.reactor`) read time only through a :class:`Clock`: call deadlines, the handshake's
deadline, timers and tickers, and ``last_frame`` (a link's staleness).  Tests hand them a
:class:`FakeClock` and move time with ``advance``: a 30 s call timeout fires in no real time,
and a timer that is not due yet cannot fire because the machine is slow.

What a clock does not govern: the stamps of when bytes arrived or left (clock sync's t1 and
t4).  Those are measurements, taken by the transports on CLOCK_MONOTONIC (the kernel's receive
stamp, the byte count at the wake-up); a link uses them only when its clock is that same
timeline (``real``).  Under a fake clock, every time a link hands out is the fake clock's.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Protocol

__all__ = ["SYSTEM_CLOCK", "Clock", "FakeClock", "SystemClock"]


def _never() -> None:
    """What ``watch`` returns when there is nothing to stop."""


class Clock(Protocol):
    """What the host side reads time from."""

    #: True: time passes by itself on CLOCK_MONOTONIC, the timeline of the transports' stamps
    #: (they are then tighter than the clock's own reading, and used); False: it moves only
    #: when advanced, and then tells its watchers
    real: bool

    def monotonic_ns(self) -> int:
        """Monotonic time, ns."""
        ...

    def monotonic(self) -> float:
        """Monotonic time, s (the deadlines and timers of the link engine)."""
        ...

    def realtime_ns(self) -> int:
        """Wall-clock time (CLOCK_REALTIME), ns: what published host times are counted in."""
        ...

    def watch(self, wake: Callable[[], None]) -> Callable[[], None]:
        """Call ``wake()`` whenever time moves other than by passing (a fake clock advanced),
        so a thread asleep until a deadline looks again; returns what stops it.  The system
        clock never calls it."""
        ...


class SystemClock:
    """The machine's clocks (``time.monotonic_ns`` and ``time.time_ns``)."""

    real = True
    # the builtins themselves: no Python frame per reading on the sample path
    monotonic_ns = staticmethod(time.monotonic_ns)
    monotonic = staticmethod(time.monotonic)
    realtime_ns = staticmethod(time.time_ns)

    def watch(self, wake: Callable[[], None]) -> Callable[[], None]:
        return _never  # time only passes: a sleeper's own timeout is enough

    def __repr__(self) -> str:
        return "<SystemClock>"


#: the default clock of every link, board and loop
SYSTEM_CLOCK = SystemClock()


class FakeClock:
    """Virtual time for tests: it stands still until :meth:`advance` moves it, and then wakes
    every thread that sleeps towards a deadline on it (the links' readers, the I/O loop), so
    what became due runs at once.  Thread-safe.

    It starts at ``start`` s (not 0: 0 means "unset" in some stamps) and its wall clock is its
    monotonic time plus ``realtime_offset_ns``."""

    real = False

    def __init__(self, start: float = 1000.0, realtime_offset_ns: int = 1_700_000_000 * 10**9):
        self._ns = round(start * 1e9)
        self._offset = realtime_offset_ns
        self._lock = threading.Lock()
        self._watchers: dict[int, Callable[[], None]] = {}
        self._next_watch = 0

    def monotonic_ns(self) -> int:
        return self._ns

    def monotonic(self) -> float:
        return self._ns / 1e9

    def realtime_ns(self) -> int:
        return self._ns + self._offset

    def advance(self, seconds: float) -> None:
        """Move time forward by ``seconds`` (>= 0) and wake whoever watches."""
        if not seconds >= 0:  # (NaN too)
            raise ValueError(f"a clock goes forward only: advance({seconds!r})")
        with self._lock:
            self._ns += round(seconds * 1e9)
            watchers = list(self._watchers.values())
        for wake in watchers:
            wake()

    def watch(self, wake: Callable[[], None]) -> Callable[[], None]:
        with self._lock:
            key = self._next_watch
            self._next_watch += 1
            self._watchers[key] = wake

        def stop() -> None:
            with self._lock:
                self._watchers.pop(key, None)

        return stop

    def __repr__(self) -> str:
        return f"<FakeClock at {self._ns / 1e9:.9f} s>"
