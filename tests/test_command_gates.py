"""Who may move the robot through the standard command topics (docs/security.md, "The standard
command topics"): ``/<board>/<actuator>/command`` (Float64) and ``/joint_commands`` (JointState)
pass ``[daemon] commands`` as every command topic does, and a joint command passes it twice: as
``/joint_commands``, then as the actuator's ``/command`` it is routed to.  The rig's board file
runs as a virtual board in a process of its own."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from missing_link.daemon import Daemon
from missing_link.daemon.config import parse_config
from missing_link.daemon.control.allowlist import CommandRefused

from .helpers import board_process, wait_for

RIG = Path(__file__).resolve().parent.parent / "examples" / "boards" / "thesis-rig.py"


def robot(url: str, allowed: list[str]) -> Daemon:
    doc = tomllib.loads(
        f'[daemon]\npublishers = ["bus"]\ncommands = {allowed!r}\n'
        f'[[board]]\nurl = "{url}"\n'
        '[joints.pan]\nstate = "rig/servo"\ncommand = "rig/servo"\n'
    )
    return Daemon(parse_config(doc))


def refused(d: Daemon) -> dict[str, int]:
    return {s["publisher"]: s["commands_refused"] for s in d.publisher_status()
            if s.get("commands_refused")}  # fmt: skip


@pytest.mark.slow
def test_a_joint_command_passes_the_allow_list_as_itself_and_as_its_actuators_command() -> None:
    with board_process("--file", str(RIG)) as url:
        with robot(url, ["/joint_commands"]) as d:
            assert d.wait_until_up(20), d.status()
            with pytest.raises(CommandRefused, match="/rig/servo/command refused"):
                d.send("/rig/servo/command", 0.5)
            d.send("/joint_commands", {"name": ["pan"], "position": [0.5]})  # (admitted...)
            assert wait_for(lambda: refused(d).get("bus") == 2, 10), refused(
                d
            )  # (...its route not)
            assert d.status()[0]["commands"] == 0  # the board heard nothing
            joints = next(s for s in d.publisher_status() if s.get("publisher") == "joints")
            assert joints["commands"] == 0 and joints["refused_by_kind"] == {"not allowed": 1}
        with robot(url, ["/joint_commands", "/rig/*/command"]) as d:
            assert d.wait_until_up(20), d.status()
            d.send("/joint_commands", {"name": ["pan"], "position": [0.5]})
            assert wait_for(lambda: d.status()[0]["commands"] == 1, 10), d.status()
            d.send("/rig/servo/command", 0.25)
            assert wait_for(lambda: d.status()[0]["commands"] == 2, 10), d.status()
            assert refused(d) == {}
