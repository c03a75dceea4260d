"""Who may move the robot (docs/security.md): commands are opt-in per face, and only the
actuator topics of the daemon's allow-list take commands at all.

Every face that can carry commands (the in-process bus, ``zenoh``, ``ros2``, ``ros1``) has
``takes_commands``: its ``commands = true|false`` option, by default true only where the face
listens on loopback alone (publishers/*.py say how each decides).  ``[daemon] commands`` lists
the command topics (patterns: ``*`` within a level, ``**`` across; default ``["**"]``: all) that
take commands.  A command that arrives where it may not is refused: not handed to the board,
counted per face (``commands_refused`` on ``/diagnostics``) and said in the log (rate-limited:
logs.py).  The face keeps its subscription, so a refusal is seen and counted, not silent.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Sequence
from typing import Any

from ..publishers.bus import topic_pattern

log = logging.getLogger(__name__)

Handler = Callable[[Any], None]


class CommandGate:
    def __init__(self, allowed: Sequence[str] = ("**",)) -> None:
        self.allowed = list(allowed)
        self._patterns = [topic_pattern(p) for p in self.allowed]
        self.refused: dict[str, int] = {}  #: face -> commands refused
        self._lock = threading.Lock()

    def allows(self, topic: str) -> bool:
        return any(p.match(topic) for p in self._patterns)

    def wrap(self, face: str, takes_commands: bool, topic: str, handler: Handler) -> Handler:
        """``handler`` where ``face`` may command ``topic``, else one that refuses and counts."""
        if takes_commands and self.allows(topic):
            return handler
        why = (
            f"commands are off on {face} (its `commands` option)"
            if not takes_commands
            else "not in [daemon] commands"
        )

        def refuse(_command: Any) -> None:
            with self._lock:
                self.refused[face] = self.refused.get(face, 0) + 1
            log.warning("%s: a command on %s refused: %s", face, topic, why)

        return refuse
