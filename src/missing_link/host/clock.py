"""The host side's one clock, passed in (trio's ``MockClock`` is the model): the system's, or a
fake one whose time stands still until a test advances it
(:class:`missing_link.testing.FakeClock`, shipped for library users' tests too).

A link engine (:mod:`.link`), a :class:`~missing_link.host.board.Board`, the shared I/O loop
(:mod:`.reactor`) and the daemon (``Daemon(clock=...)``: its sessions' supervisors, liveness,
the failsafe's and other background reads, updates, the listener) read time only through a
:class:`Clock`: call deadlines, the handshake's deadline, timers and tickers, the supervisor's
sleeps, and ``last_frame`` (a link's staleness), all on one timeline.  Tests hand them a fake
clock and move time with ``advance``: a 30 s call timeout fires in no real time, and a timer
that is not due yet cannot fire because the machine is slow.

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

__all__ = ["SYSTEM_CLOCK", "Clock", "SystemClock"]


def never() -> None:
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

    def wait(self, event: threading.Event, timeout: float) -> bool:
        """Sleep until ``event`` is set or ``timeout`` s of this clock passed; whether it was
        set (a session's supervisor sleeps so)."""
        ...


class SystemClock:
    """The machine's clocks (``time.monotonic_ns`` and ``time.time_ns``)."""

    real = True
    # the builtins themselves: no Python frame per reading on the sample path
    monotonic_ns = staticmethod(time.monotonic_ns)
    monotonic = staticmethod(time.monotonic)
    realtime_ns = staticmethod(time.time_ns)

    def watch(self, wake: Callable[[], None]) -> Callable[[], None]:
        return never  # time only passes: a sleeper's own timeout is enough

    def wait(self, event: threading.Event, timeout: float) -> bool:
        return event.wait(timeout)

    def __repr__(self) -> str:
        return "<SystemClock>"


#: the default clock of every link, board and loop
SYSTEM_CLOCK = SystemClock()
