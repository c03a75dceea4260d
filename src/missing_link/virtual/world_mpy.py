"""The world beside a board file's firmware under MicroPython (virtual/mpyboard.py): the world
(missing_link/world) runs here, in the Python process that starts node, and node's side
(world/worldtick.mjs) asks it for a tick when the simulation's time gets there, over two pipes.

Theory of operation
-------------------
:class:`NodeWorld` makes the pipes and gives node their ends (``--world-fds REQ,RESP``, passed
through as the same descriptors); a thread of its own (``world``) answers node's lines, one
JSON line each: ``HELLO <now>`` (the simulation's µs at the firmware's start: the world's
clock starts there) with the parts numbered for worldfeed.attach, the actuator reads wanted
before each tick and the tick's length; ``T <now> <used> <values...>`` with a batch of ticks
(worldlink.py's ahead: the one at ``now`` and those of up to the next 100 ms on time, each its
time, feed calls and encoders' edges), ``used`` saying how many of the last batch node made
happen (the rest were not: the actuators changed; the world goes back).  Node blocks on the
answer, so the world steps in the simulation's time, in lockstep with it; it asks once a batch,
not once a tick: a wake-up of this thread costs some 250 µs of CPU more than its tick's sums
(its code and data cold), most of what the world cost under MicroPython.  A world that raises
answers ``{"error": ...}`` once and node stops the board with it (as a firmware that crashed).
Pushes by hand (worldctl.py) reach the world link from their own threads, as on CPython.
"""

from __future__ import annotations

import json
import os
import threading
from typing import Any, BinaryIO

from ..errors import MissingLinkError
from ..world.spec import WorldSpec
from ..world.world import World
from .worldlink import MAX_CATCHUP_US, WorldLink


class NodeWorld:
    """``spec``'s world for ``board`` (a board file's dict), seeded by ``seed``, for a node
    that gets :meth:`node_args` and :attr:`pass_fds`; ``absent``: parts left unplugged."""

    def __init__(
        self, spec: WorldSpec, board: dict[str, Any], seed: int, absent: frozenset[str]
    ) -> None:
        self.spec, self.board, self.seed, self.absent = spec, board, seed, absent
        self.link: WorldLink | None = None
        self.ready = threading.Event()
        req_r, self._req_w = os.pipe()
        self._resp_r, resp_w = os.pipe()
        self._in: BinaryIO = os.fdopen(req_r, "rb")
        self._out: BinaryIO = os.fdopen(resp_w, "wb")
        self.pass_fds = (self._req_w, self._resp_r)
        self.failed: str | None = None
        self._thread = threading.Thread(target=self._serve, name="world", daemon=True)

    def node_args(self) -> list[str]:
        return ["--world-fds", f"{self._req_w},{self._resp_r}"]

    def started(self) -> None:
        """Node has its ends: ours of them close here, and the world serves."""
        os.close(self._req_w)
        os.close(self._resp_r)
        self._thread.start()

    def _link(self) -> WorldLink:
        if not self.ready.wait(30) or self.link is None:
            raise WorldNotThere("the world is not there: the firmware did not start under node")
        return self.link

    def push(self, kind: str, args: dict[str, Any]) -> None:
        """A push by hand (worldctl.py): the world link's, once node said hello."""
        self._link().push(kind, args)

    def state(self) -> dict[str, Any]:
        return self._link().state()

    def _serve(self) -> None:
        try:
            for raw in self._in:
                answer = self._answer(raw.decode().split())
                self._out.write(json.dumps(answer, separators=(",", ":")).encode() + b"\n")
                self._out.flush()
                if "error" in answer:
                    return
        except (OSError, ValueError):
            return  # (node went away)
        finally:
            self._in.close()
            self._out.close()

    def _answer(self, words: list[str]) -> dict[str, Any]:
        try:
            if words[0] == "HELLO":
                return self._hello(int(words[1]))
            if words[0] == "T" and self.link is not None:
                now, used, *values = map(int, words[1:])
                ticks = self.link.ahead(now, used, values)
                return {"ticks": [[t, [[fn, *args] for fn, args in calls], edges]
                                  for t, calls, edges in ticks],
                        "due": self.link.due_us()}  # fmt: skip
            return {"error": f"not a request of worldtick.mjs: {' '.join(words)[:80]!r}"}
        except Exception as e:  # noqa: BLE001 - said to node once: the board stops with it
            self.failed = f"{type(e).__name__}: {e}"
            return {"error": self.failed}

    def _hello(self, now: int) -> dict[str, Any]:
        self.link = WorldLink(World(self.spec, self.board, now, self.seed), self.board,
                              self.absent)  # fmt: skip
        self.link.made_first = True  # (worldtick.mjs makes a batch's first tick at once)
        self.ready.set()
        return {"attach": [list(args) for _fn, args in self.link.attach()],
                "reads": [[fn, *args] for fn, args in self.link.reads],
                "tick_us": self.link.tick_us, "catchup_us": MAX_CATCHUP_US}  # fmt: skip


class WorldNotThere(MissingLinkError):
    """A push by hand before the firmware (and with it the world) started under node."""
