"""The command gate for a change of an actuator's run-time configuration
(daemon/session/run_config.py): the keys of an actuator are commands, so a face changes them only
where it takes commands and ``[daemon] commands`` admits the actuator's command topic
(allowlist.py)."""

from __future__ import annotations

from typing import Any

from ..session.run_config import Guard
from .allowlist import CommandGate, CommandRefused


def config_guard(gate: CommandGate, session: Any, by: str, commands: bool) -> Guard:
    """The guard for a configuration change of ``session``'s actuators by face ``by`` (whose
    ``commands`` option is ``commands``): raises CommandRefused, counted under ``by``."""

    def check(actuators: list[str]) -> None:
        for name in actuators:
            found = [t for t in session.topics.values() if t.transducer.name == name]
            call = found[0].transducer.call if found else None
            topic = session.command_topic(call or "") or f"/{session.name}/{name}/cmd"
            try:
                gate.check_face(by, commands, topic)
            except CommandRefused as e:
                raise CommandRefused(
                    f"{session.name}: the keys of {name} are commands: {e}"
                ) from None

    return check
