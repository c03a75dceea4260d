"""A fake of the host's clock (:class:`missing_link.host.clock.Clock`): time that stands still
until a test moves it.  Hand it to a ``Board``, a ``Reactor`` or a ``Daemon`` (``clock=``)."""

from __future__ import annotations

import threading
from collections.abc import Callable

#: how often a waiter on a fake clock looks at its event (s of real time)
_LOOK_S = 0.001


class FakeClock:
    """Virtual time for tests: it stands still until :meth:`advance` moves it, and then wakes
    every thread that sleeps towards a deadline on it (the links' readers, the I/O loop), so
    what became due runs at once.  Thread-safe.

    It starts at ``start`` s (not 0: 0 means "unset" in some stamps) and its wall clock is its
    monotonic time plus ``realtime_offset_ns``.

    ``autojump``: a :meth:`wait` whose event is not set moves time on to its end at once (trio's
    autojump, with no threshold), for one thread that only sleeps on this clock (a session's
    supervisor driven alone): hours of its life run in no real time.  Otherwise ``wait``
    returns when the event is set or a test advanced the clock past its end."""

    real = False

    def __init__(
        self,
        start: float = 1000.0,
        realtime_offset_ns: int = 1_700_000_000 * 10**9,
        *,
        autojump: bool = False,
    ) -> None:
        self.autojump = autojump
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

    def wait(self, event: threading.Event, timeout: float) -> bool:
        if event.is_set():
            return True
        end = self._ns + round(max(0.0, timeout) * 1e9)
        if self.autojump:
            self.advance(max(0.0, (end - self._ns) / 1e9))
            return event.is_set()
        # (an event has no hook: looked at every millisecond of real time, until the fake
        # time is past the end or the event is set)
        while self._ns < end:
            if event.wait(_LOOK_S):
                return True
        return event.is_set()

    def __repr__(self) -> str:
        return f"<FakeClock at {self._ns / 1e9:.9f} s>"
