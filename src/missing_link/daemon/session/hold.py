"""A board's port let go for a while: an AVR board's update writes through its bootloader with
avrdude, which needs the serial port the daemon holds (daemon/control/updates.py).

Theory of operation
-------------------
``take(seconds)`` lets go until ``release()`` or the time is up, whichever comes first (a client
that died mid-update cannot keep the port away for good).  The session's supervisor calls
``wait(stop)`` before each connect: while the hold lasts it waits there, ``parked`` set, so the
one who took the hold knows the port is free once ``parked`` is (``wait_parked``); then it
connects again as after any lost link.
"""

from __future__ import annotations

import threading

from ...host.clock import SYSTEM_CLOCK, Clock


class PortHold:
    def __init__(self, clock: Clock = SYSTEM_CLOCK) -> None:
        self.clock = clock  #: the daemon's
        self._until = 0.0
        self._changed = threading.Condition()
        self.parked = threading.Event()  #: the supervisor waits here: the port is free

    def take(self, seconds: float) -> None:
        with self._changed:
            self._until = self.clock.monotonic() + seconds
            self._changed.notify_all()

    def release(self) -> None:
        with self._changed:
            self._until = 0.0
            self._changed.notify_all()

    @property
    def held(self) -> bool:
        return self.clock.monotonic() < self._until

    def wait(self, stop: threading.Event) -> None:
        """While the hold lasts (and ``stop`` is not set): the supervisor's, before it
        connects."""
        with self._changed:
            while not stop.is_set() and (left := self._until - self.clock.monotonic()) > 0:
                self.parked.set()
                self._changed.wait(min(left, 0.1))
            self.parked.clear()

    def wait_parked(self, timeout: float) -> bool:
        """Until the supervisor waits at the hold (the port is free), at most ``timeout``."""
        return self.parked.wait(timeout)
