"""Who may move the robot (docs/security.md): commands are opt-in per face, and only the
actuator topics of the daemon's allow-list take commands at all.

Every face that can carry commands (the in-process bus, ``zenoh``, ``ros2``, ``ros1``) has
``takes_commands``: its ``commands = true|false`` option, by default true only where the face
listens on loopback alone (publishers/*.py say how each decides).  ``[daemon] commands`` lists
the command topics (patterns: ``*`` within a level, ``**`` across; default ``["**"]``: all) that
take commands.  A command that arrives where it may not is refused: not handed to the board,
counted per face (``commands_refused`` on ``/diagnostics``) and said in the log: on a face's
command topics once per face and kind (commands off there: with what turns them on, the face's
``commands_how``; or not in the list), the rest counted.  The face keeps its subscription, so a
refusal is seen and counted, not silent.

The list holds on every path that reaches an actuator, not only on the faces' command topics: a
plain call of an actuator's function (``Daemon.call``, the control endpoint behind
``missing-link call``, ``Daemon.trigger_at``), an ``a2jAt`` that would call one later, and
``Daemon.send`` are refused the same way (``check``: CommandRefused, counted under the path's
name: ``api``, ``control``, ``bus``), named by the actuator's command topic.  So is a change
of an actuator's run-time configuration (its keys are commands: daemon/session/run_config.py) from
any face (``check_face``: the face's ``commands`` first, then the list).  And so are the paths
that change what every actuator of a board does or let go of it (``check_all``: the list must
admit the command topic of every actuator the board has, counted under the path's name): a
plain call of a configuration function (``a2jConfigSet``, ``a2jConfigReset``: through a raw call
the daemon does not work out which keys; ``missing-link config`` checks key by key), a firmware
update (the control endpoint's ``update``, or its ``a2jFw*`` calls one by one) and ``release``
(the daemon lets go of the board's port: whoever takes it drives the board).  Before, a control
``call BOARD a2jConfigSet`` set ``servo.failsafe_ms = 0`` under a list that admitted nothing
(issue 43.7).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Sequence
from typing import Any

from ...errors import MissingLinkError
from ...publishers.bus import topic_pattern

log = logging.getLogger(__name__)

Handler = Callable[[Any], None]


#: functions whose plain call changes what every actuator of a board may do: its run-time
#: configuration (an actuator's keys are commands) and its firmware
BOARD_WIDE = frozenset(
    ("a2jConfigSet", "a2jConfigReset", "a2jFwBegin", "a2jFwStage", "a2jFwSwitch", "a2jFwConfirm")
)


class CommandRefused(MissingLinkError):
    """A command the allow-list (``[daemon] commands``) does not admit: nothing was sent."""


def called_function(function: str, payload: bytes, functions: Sequence[str]) -> str:
    """The function a call of ``function`` with ``payload`` ends up running on the board: for
    ``a2jAt`` the one its payload names ([q host ns][B function index][args]), and so on down
    an ``a2jAt`` of an ``a2jAt`` (boards refuse that now, but an older one ran it: the list
    must hold whatever the board does); for ``a2jMany`` its target ([B function index]...: a
    staged firmware is written so), else itself."""
    while len(payload) >= 1:
        if function == "a2jAt" and len(payload) >= 9 and payload[8] < len(functions):
            function, payload = functions[payload[8]], payload[9:]
        elif function == "a2jMany" and payload[0] < len(functions):
            function, payload = functions[payload[0]], b""
        else:
            break
    return function


class CommandGate:
    def __init__(self, allowed: Sequence[str] = ("**",)) -> None:
        self.allowed = list(allowed)
        self._patterns = [topic_pattern(p) for p in self.allowed]
        self.refused: dict[str, int] = {}  #: face (or path) -> commands refused
        self._said: set[tuple[str, str]] = set()  #: (face, kind of refusal) said once
        self._lock = threading.Lock()

    def allows(self, topic: str) -> bool:
        return any(p.match(topic) for p in self._patterns)

    def check(self, path: str, topic: str) -> None:
        """Raise CommandRefused (counted under ``path``) unless the list admits ``topic``."""
        if self.allows(topic):
            return
        self._count(path)
        log.warning("%s: a command on %s refused: not in [daemon] commands", path, topic)
        raise CommandRefused(f"a command on {topic} refused: not in [daemon] commands")

    def check_all(self, path: str, topics: Sequence[str], what: str) -> None:
        """Raise CommandRefused (counted once under ``path``) unless the list admits every one
        of ``topics`` (the command topics of a board's actuators): ``what`` (a call or an op
        that changes what every one of them does, or lets go of the board) names it."""
        barred = [t for t in topics if not self.allows(t)]
        if not barred:
            return
        self._count(path)
        log.warning("%s: %s refused: %s not in [daemon] commands", path, what, barred[0])
        raise CommandRefused(
            f"{what} refused: it changes what {', '.join(barred)} moves, which [daemon] "
            "commands does not list"
        )

    def check_face(self, face: str, takes_commands: bool, topic: str) -> None:
        """``check``, and refused (counted under ``face``) where ``face`` takes no commands:
        a change of an actuator's configuration (daemon/session/run_config.py)."""
        if takes_commands:
            return self.check(face, topic)
        self._count(face)
        log.warning("%s: a command on %s refused: commands are off on %s", face, topic, face)
        raise CommandRefused(
            f"a command on {topic} refused: commands are off on {face} (its `commands` option)"
        )

    def _count(self, path: str, kind: str = "") -> bool:
        """Count a refusal on ``path``; True the first time ``kind`` is refused there."""
        with self._lock:
            self.refused[path] = self.refused.get(path, 0) + 1
            first = (path, kind) not in self._said
            self._said.add((path, kind))
            return first

    def wrap(
        self, face: str, takes_commands: bool, topic: str, handler: Handler, how: str = ""
    ) -> Handler:
        """``handler`` where ``face`` may command ``topic``, else one that refuses and counts.
        ``how``: what turns the face's commands on (its publisher's ``commands_how``).  The
        first refusal of each kind on a face says why and what to set, once; the rest are
        counted (a controller sends every cycle: a line each would bury the log)."""
        if takes_commands and self.allows(topic):
            return handler
        if not takes_commands:
            kind = "off"
            why = f"commands are off on {face} ({how or 'its `commands` option'})"
        else:
            kind, why = "list", f"not in [daemon] commands (add {topic} to take it)"

        def refuse(_command: Any) -> None:
            if self._count(face, kind):
                log.warning("%s: a command on %s refused: %s; further refusals are counted "
                            "(commands_refused on /diagnostics)", face, topic, why)  # fmt: skip

        return refuse
