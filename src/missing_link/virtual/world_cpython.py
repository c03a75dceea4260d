"""The world beside a board file's firmware on CPython (virtual/boardfile.py): the world link
(worldlink.py) ticked from the firmware's own loop, its calls made on the simulator's
worldfeed.py in this process.

Theory of operation
-------------------
The firmware's link is handed to it wrapped (:class:`WorldAtTheLink`): at every turn of its loop
(its read of the link comes first) the world is pumped, and its sleeps end no later than the
world's next tick, so ticks come when due by the board's clock.  A tick reads the actuators
through worldfeed.py and makes the feed calls of the world's tick then: the world computes its
ticks 100 ms at a time (worldlink.py's ahead and Ahead: a tick on its own ran cold, the
firmware's loop between, several times its sums), asked again when the actuators change;
the encoders' edges of the tick ahead wait in :attr:`CPythonWorld.pending` and each is
delivered at the first turn after its time, with the board's clock held at the edge's own time
while its interrupt handler runs (:class:`BoardClock`), as a board's handler runs when the
edge comes.  Nothing here is the firmware's: it sees its pins, registers and clock.
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
        self.ahead = Ahead(link)  # (the world's ticks 100 ms at a time: a tick costs it less)
        self.clock = clock
        self.pending: list[Edge] = []
        self.ticks = 0
        self.edges = 0
        for fn, args in link.attach():
            getattr(worldfeed, fn)(*args)

    def pump(self) -> None:
        now = self.clock()
        if now >= self.ahead.due_us():
            values = [getattr(worldfeed, fn)(*args) for fn, args in self.link.reads]
            _t, calls, edges = self.ahead.tick(now, values)
            for fn, args in calls:
                getattr(worldfeed, fn)(*args)
            for e in edges:
                bisect.insort(self.pending, e)
            self.ticks += 1
        n = bisect.bisect_right(self.pending, (now, 1 << 62))
        if n:
            due, self.pending = self.pending[:n], self.pending[n:]
            try:
                for t, a, b, d in due:
                    self.clock.held = t
                    worldfeed.step_at(t, a, b, d)
            finally:
                self.clock.held = None
            self.edges += n

    def until_due_us(self) -> int:
        return max(0, self.ahead.due_us() - self.clock())


class WorldAtTheLink:
    """The firmware's link, with the world pumped at each read and no sleep past its next tick;
    everything else is the link's."""

    def __init__(self, link: Any, world: CPythonWorld) -> None:
        self._link = link
        self._world = world

    def read(self) -> Any:
        self._world.pump()
        return self._link.read()

    def wait(self, us: int) -> None:
        self._link.wait(min(us, self._world.until_due_us()))

    def __getattr__(self, name: str) -> Any:
        return getattr(self._link, name)
