"""A board's actuator commands: checked where they arrive, the latest per actuator kept, and
called on the board by the session's supervisor (never on a face's thread).

Any face (the bus, Zenoh, rclpy, rospy) hands a command to the handler of its actuator; the
handler checks it against the transducer's data type, keeps it as the latest for that actuator
(an older one not yet sent is replaced: a servo wants the newest position, not a backlog) and
wakes the supervisor, which calls the actuator's function (``call=`` in its descriptor) with
it.  A refused call is counted and said once per failure, never raised into a face.

A timed command (``Command.at_ns``: a host time to act at; board/timing.py) is not replaced by
a later one: each goes to the board as ``a2jAt`` in arrival order, the board's clock map pushed
first, and the board acts at that host time or refuses (past, beyond what the map vouches for,
no map): refusals are counted and said, and a caller waiting on ``Command.done`` gets them.
"""

from __future__ import annotations

import logging
import struct
import threading
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any

from ..descriptors import Transducer
from ..errors import MissingLinkError
from ..host.board import Board
from ..topics import Command, Update

log = logging.getLogger(__name__)

MAX_TIMED = 64  #: timed commands waiting for the supervisor, per board


class Actuators:
    def __init__(self, wake: Callable[[], None], on_error: Callable[[str], None]) -> None:
        """``wake()``: a command is pending (wake the supervisor); ``on_error(text)``: a call
        the board refused or a link that failed under it."""
        self._wake = wake
        self._on_error = on_error
        self._pending: dict[str, tuple[Transducer, Any]] = {}  # latest command per actuator
        self._timed: list[tuple[Transducer, Any, int, Future[int] | None]] = []
        self._lock = threading.Lock()
        self.commands = 0
        self.command_errors = 0

    def handler(self, t: Transducer) -> Callable[[Any], None]:
        """The command handler for actuator ``t``: raises ValueError for a value it cannot
        take (the face counts it), else queues it (latest wins) and wakes the supervisor."""

        def handle(value: Any) -> None:
            timed: Command | None = None
            if isinstance(value, Command):
                timed = value if value.at_ns is not None else None
                value = value.values
            if isinstance(value, Update):
                present = [v for v in value.values if v is not None]
                if not present:
                    raise ValueError(f"{t.name}: the update on {value.topic.name} has no value")
                value = present[0]
            elif isinstance(value, (list, tuple)):
                value = value[0]
            if not t.legal(value):
                raise ValueError(f"{t.name}: {value!r} is not a legal {t.dtype} command")
            with self._lock:
                if timed is None:
                    self._pending[t.name] = (t, value)
                elif len(self._timed) >= MAX_TIMED:
                    raise ValueError(f"{t.name}: {MAX_TIMED} timed commands wait already")
                else:
                    assert timed.at_ns is not None
                    self._timed.append((t, value, timed.at_ns, timed.done))
            self._wake()

        return handle

    def run(self, board: Board, stopping: Callable[[], bool], push_map: Callable[[], None]) -> None:
        """Call the board with every pending command (the supervisor's thread); ``push_map``
        hands the board the current clock map (before timed commands)."""
        with self._lock:
            pending, self._pending = self._pending, {}
            timed, self._timed = self._timed, []
        if timed:
            self._run_timed(board, timed, stopping, push_map)
        for t, value in pending.values():
            try:
                board.call_ok(str(t.call), t.value_struct().pack(value))
                self.commands += 1
            except MissingLinkError as e:
                if stopping():
                    return  # closing: a command cut short is not an error worth a line
                self.command_errors += 1
                self._on_error(str(e))
                log.warning("%s", e)
            except struct.error as e:
                self.command_errors += 1
                log.warning("%s: bad command value %r: %s", t.name, value, e)

    def _run_timed(
        self,
        board: Board,
        timed: list[tuple[Transducer, Any, int, Future[int] | None]],
        stopping: Callable[[], bool],
        push_map: Callable[[], None],
    ) -> None:
        try:
            push_map()
        except MissingLinkError as e:
            for _t, _v, _at, done in timed:
                if done is not None:
                    done.set_exception(e)
            return
        for t, value, at_ns, done in timed:
            try:
                if "a2jAt" not in board.index:
                    raise MissingLinkError(f"{board.name}: no a2jAt: it cannot act at a time")
                payload = struct.pack("<qB", at_ns, board.index[str(t.call)])
                reply = board.call_ok("a2jAt", payload + t.value_struct().pack(value))
                tick = struct.unpack("<Q", reply[:8])[0] if len(reply) >= 8 else -1
                self.commands += 1
                if done is not None:
                    done.set_result(tick)
            except (MissingLinkError, struct.error) as e:
                if stopping():
                    return
                self.command_errors += 1
                self._on_error(f"{t.name}: timed command refused: {e}")
                log.warning("%s: timed command at %d refused: %s", t.name, at_ns, e)
                if done is not None:
                    done.set_exception(e)
