"""Commands beyond their actuator's type over the network faces (issue 43.1): a ``Float64`` of
1e300 on ``/<board>/<actuator>/command`` (an H-bridge, a stepper) and a ``/joint_commands``
effort of 1e300, from a plain Zenoh + rosbags process and from a stock rclpy node, ten a
second, with a legal command beside them.  The rover's board file runs as the CPython virtual
board.  Before, each such value ended the board's session (``OverflowError: float too large to
pack with f format``): the board reconnected again and again and its sensors went dark.  Now
each is refused where it meets its type, counted (``values_refused``, on ``/diagnostics`` too)
and the board's one session stays up, its legal commands going through."""

from __future__ import annotations

import json
import subprocess
import sys
import tomllib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from missing_link.daemon import Daemon
from missing_link.daemon.config import parse_config

from .helpers import board_process, free_port
from .test_ros2 import ROS2_PY, ros_env, stop

HERE = Path(__file__).resolve().parent
ROVER = HERE.parent / "examples" / "boards" / "rover.py"
pytestmark = pytest.mark.slow
BAD = ["/rover/motor_l/command=1e300", "/rover/mast/command=-1e300"]
GOOD = "/rover/motor_r/command=0.5"
JOINT = "left_wheel=effort=1e300"


def toml(url: str, publishers: str, extra: str = "") -> str:
    return f"""
[daemon]
publishers = {publishers}
diagnostics_period = 0.5
[[board]]
url = "{url}"
timeout = 2.0
[joints.left_wheel]
command = "rover/motor_l"
{extra}
"""


@pytest.fixture(scope="module")
def rover() -> Iterator[str]:
    with board_process("--file", str(ROVER)) as url:
        yield url


def args(flag: str) -> list[str]:
    return [x for spec in [*BAD, GOOD] for x in (flag, spec)] + ["--joint", JOINT]


def test_zenoh_values_beyond_the_type_are_refused_and_the_board_stays_up(rover: str) -> None:
    port = free_port()
    extra = f'[zenoh]\nlisten = ["tcp/127.0.0.1:{port}"]\nconnect = []\n'
    with Daemon(parse_config(tomllib.loads(toml(rover, '["bus", "zenoh"]', extra)))) as d:
        assert d.wait_until_up(30), d.failures()
        r = subprocess.run(
            [sys.executable, str(HERE / "zenoh_standard_listener.py"),
             "--connect", f"tcp/127.0.0.1:{port}", "--seconds", "4", *args("--float64")],
            capture_output=True, text=True, timeout=60,
        )  # fmt: skip
        assert r.returncode == 0, r.stderr[-3000:]
        (s,) = d.status()
        zenoh = next(p for p in d.publisher_status() if p.get("publisher") == "zenoh")
        joints = next(p for p in d.publisher_status() if p.get("publisher") == "joints")
    assert s["state"] == "up" and s["connects"] == 1, s  # (before: one reconnect per value)
    assert s["values_refused"] >= 30 and s["commands"] >= 10, s
    assert zenoh["commands_rejected"] >= 20, zenoh
    assert joints["commands_refused"] >= 10, joints


def _board_status(diagnostics: list[dict[str, Any]], board: str) -> dict[str, str]:
    for msg in reversed(diagnostics):
        for st in msg["status"]:
            if st["name"] == f"missing_link: {board}":
                return {kv["key"]: kv["value"] for kv in st["values"]}
    raise AssertionError(f"no /diagnostics of {board}")


@pytest.mark.skipif(not ROS2_PY.exists(), reason=f"ROS 2 wheels not installed ({ROS2_PY})")
def test_rclpy_values_beyond_the_type_are_refused_and_the_board_stays_up(
    rover: str, tmp_path: Path
) -> None:
    cfg = tmp_path / "robot.toml"
    cfg.write_text(toml(rover, '["bus", "ros2"]'))
    env = ros_env()
    p = subprocess.Popen(
        [str(ROS2_PY), "-m", "missing_link", "run", "--config", str(cfg), "--duration", "60"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
    )  # fmt: skip
    try:
        r = subprocess.run(
            [str(ROS2_PY), str(HERE / "ros2_standard_listener.py"), "--seconds", "8",
             "--min", "1000000", "--sub", "/diagnostics=diagnostic_msgs/msg/DiagnosticArray",
             *args("--float64")],
            capture_output=True, text=True, env=env, timeout=120,
        )  # fmt: skip
    finally:
        err = stop(p)
    assert r.returncode == 0, r.stderr[-3000:]
    got = json.loads(r.stdout.strip().splitlines()[-1])
    assert got["sent"] >= 30, got["sent"]
    s = _board_status(got["received"]["/diagnostics"], "rover")
    assert s["state"] == "up" and s["connects"] == "1", s  # (before: one reconnect per value)
    assert int(s["values_refused"]) >= 10 and int(s["commands"]) >= 5, s
    assert "Traceback" not in err and "OverflowError" not in err, err[-3000:]
