"""A command a face may not take is said once, with what turns commands on there, then counted
(issue 45.2: the README's `ros2 topic pub` was refused a line per command, naming neither the
variable nor the key).  The real rclpy case: tests/test_ros2.py."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest

from missing_link.daemon.control.allowlist import CommandGate
from missing_link.publishers.ros2 import COMMANDS_HOW

ROOT = Path(__file__).resolve().parent.parent


def test_a_face_with_commands_off_says_what_turns_them_on_once(
    caplog: pytest.LogCaptureFixture,
) -> None:
    gate = CommandGate(["/rig/servo/*"])
    sent: list[object] = []
    servo = gate.wrap("ros2", False, "/rig/servo/command", sent.append, COMMANDS_HOW)
    motor = gate.wrap("ros2", False, "/rig/motor/command", sent.append, COMMANDS_HOW)
    listed = gate.wrap("zenoh", True, "/rig/motor/cmd", sent.append, "anything")
    with caplog.at_level(logging.WARNING, logger="missing_link.daemon.control.allowlist"):
        for _ in range(3):
            servo(0.5)
            motor(0.1)
            listed(1)
    said = [r.getMessage() for r in caplog.records]
    assert sent == [] and gate.refused == {"ros2": 6, "zenoh": 3}
    assert len(said) == 2, said  # (one per face and kind: not one per command)
    assert "ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST" in said[0]
    assert "[ros2] commands = true" in said[0] and "further refusals are counted" in said[0]
    assert "not in [daemon] commands (add /rig/motor/cmd" in said[1]


def test_the_readme_says_what_a_ros2_command_needs() -> None:
    """The README's command example works as written once its line is followed."""
    text = (ROOT / "README.md").read_text()
    block = text[text.index("### ROS 2 through rclpy") :]
    block = block[: block.index("### ROS 2 through Zenoh")]
    lines = block.splitlines()
    run = next(k for k, ln in enumerate(lines) if ln.startswith("missing-link run"))
    pub = next(k for k, ln in enumerate(lines) if ln.startswith("ros2 topic pub"))
    assert lines[run - 1].startswith("export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST"), lines
    assert run < pub and "[ros2] commands = true" in block, block
