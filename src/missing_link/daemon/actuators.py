"""A board's actuator commands: checked where they arrive, the latest per actuator kept, and
called on the board by the session's supervisor (never on a face's thread).

Any face (the bus, Zenoh, rclpy, rospy) hands a command to the handler of its actuator; the
handler checks it against the transducer's data type, keeps it as the latest for that actuator
(an older one not yet sent is replaced: a servo wants the newest position, not a backlog) and
wakes the supervisor, which calls the actuator's function (``call=`` in its descriptor) with
it.  A refused call is counted and said once per failure, never raised into a face.
"""

from __future__ import annotations

import logging
import struct
import threading
from collections.abc import Callable
from typing import Any

from ..descriptors import Transducer
from ..errors import MissingLinkError
from ..host.board import Board
from ..topics import Update

log = logging.getLogger(__name__)


class Actuators:
    def __init__(self, wake: Callable[[], None], on_error: Callable[[str], None]) -> None:
        """``wake()``: a command is pending (wake the supervisor); ``on_error(text)``: a call
        the board refused or a link that failed under it."""
        self._wake = wake
        self._on_error = on_error
        self._pending: dict[str, tuple[Transducer, Any]] = {}  # latest command per actuator
        self._lock = threading.Lock()
        self.commands = 0
        self.command_errors = 0

    def handler(self, t: Transducer) -> Callable[[Any], None]:
        """The command handler for actuator ``t``: raises ValueError for a value it cannot
        take (the face counts it), else queues it (latest wins) and wakes the supervisor."""

        def handle(value: Any) -> None:
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
                self._pending[t.name] = (t, value)
            self._wake()

        return handle

    def run(self, board: Board, stopping: Callable[[], bool]) -> None:
        """Call the board with every pending command (the supervisor's thread)."""
        with self._lock:
            pending, self._pending = self._pending, {}
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
