"""The world beside a board file's firmware on CPython (virtual/boardfile.py): the world link
(worldlink.py) ticked from the firmware's own loop, its calls made on the simulator's
worldfeed.py in this process.

Theory of operation
-------------------
The firmware's link is handed to it wrapped (:class:`WorldAtTheLink`): at every turn of its loop
(its read of the link comes first) the world is pumped: every tick whose time has come is made,
each at its own time, and every encoder edge due by now is delivered, all in time order.  The
firmware's sleeps are its own (its deadlines, the link's input): the world does not wake it.
It need not: only the firmware changes the actuators (worldfeed.py reads a PWM's duty, a pin's
level, a stepper's steps, all set by the firmware's code), so while it sleeps they hold and the
world's ticks of that time are the ones computed for them; and what the firmware sees of the
world it sees when it runs, at a read of a sensor (the latest tick at or before it, made by the
pump before) or in an edge's interrupt handler.  A tick reads the actuators through worldfeed.py
and makes the feed calls of the world's tick then: the world computes its ticks up to 100 ms at
a time (worldlink.py's ahead and Ahead: a tick on its own ran cold, the firmware's loop between,
several times its sums), asked again when the actuators change.  The encoders' edges wait in
:attr:`CPythonWorld.pending` and each is delivered with the board's clock held at the edge's
own time while its interrupt handler runs (:class:`BoardClock`), before any tick after it: a
handler sees the time and the pins it would on a board whose CPU its edge woke, and the
firmware's loop, at its next turn, every edge due by then.  Nothing here is the firmware's: it
sees its pins, registers and clock.
"""

from __future__ import annotations

import bisect
import time
from typing import Any

from .world import worldfeed
from .worldlink import Ahead, Edge, WorldLink


class BoardClock:
    """The board's clock on CPython (CLOCK_MONOTONIC in µs, as board/clock.py's), held at an
    edge's time while its interrupt is delivered."""

    def __init__(self) -> None:
        self.held: int | None = None

    def __call__(self) -> int:
        if self.held is not None:
            return self.held
        return time.monotonic_ns() // 1000


class CPythonWorld:
    def __init__(self, link: WorldLink, clock: BoardClock) -> None:
        self.link = link
        self.ahead = Ahead(link)  # (the world's ticks up to 100 ms at a time: cheaper a tick)
        self.clock = clock
        self.pending: list[Edge] = []
        self.ticks = 0
        self.edges = 0
        for fn, args in link.attach():
            getattr(worldfeed, fn)(*args)

    def pump(self) -> None:
        """Every tick due by now made and every edge due by now delivered, in time order (an
        edge at a tick's time after it)."""
        now = self.clock()
        while (due := self.ahead.due_us()) <= now:
            self._deliver(due - 1)  # (a handler may change an actuator: the tick reads it)
            values = [getattr(worldfeed, fn)(*args) for fn, args in self.link.reads]
            _t, calls, edges = self.ahead.tick(now, values)
            for fn, args in calls:
                getattr(worldfeed, fn)(*args)
            for e in edges:
                bisect.insort(self.pending, e)
            self.ticks += 1
        self._deliver(now)

    def _deliver(self, until: int) -> None:
        """The edges due by ``until``, each with the board's clock held at its time."""
        n = bisect.bisect_right(self.pending, (until, 1 << 62))
        if n:
            due, self.pending = self.pending[:n], self.pending[n:]
            try:
                for t, a, b, d in due:
                    self.clock.held = t
                    worldfeed.step_at(t, a, b, d)
            finally:
                self.clock.held = None
            self.edges += n


class WorldAtTheLink:
    """The firmware's link, with the world pumped at each read; everything else is the
    link's (its waits too: the world does not cut them)."""

    def __init__(self, link: Any, world: CPythonWorld) -> None:
        self._link = link
        self._world = world

    def read(self) -> Any:
        self._world.pump()
        return self._link.read()

    def __getattr__(self, name: str) -> Any:
        return getattr(self._link, name)
