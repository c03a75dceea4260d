"""A differential-drive rover on a Mega (issue 46.4): examples/boards/rover-mega.py's firmware,
real ATmega2560 machine code in simavr with every part simulated at its pins (``missing-link
board --file ... --runtime avr``, as a user runs it), the daemon in .venv-ros2 publishing to
ROS 2, and a stock rclpy node (tests/ros2_standard_listener.py: imports nothing of ours) that sees
its Imu, its battery and its wheels' JointState, and drives both motors with Float64: the rig's
motors turn its wheels (firmware/avr/sim/motor.c), so the encoders' joints move forward.
Loopback only (tests/fastdds_loopback.xml)."""

from __future__ import annotations

import json
import math
import subprocess
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from .helpers import board_process
from .test_ros2 import ROS2_PY, ros_env, stop

ROOT = Path(__file__).resolve().parent.parent
ROVER = ROOT / "examples" / "boards" / "rover-mega.py"
LISTENER = Path(__file__).with_name("ros2_standard_listener.py")
SUBS = {
    "/mega_rover/imu/imu": "sensor_msgs/msg/Imu",
    "/mega_rover/imu/temperature": "sensor_msgs/msg/Temperature",
    "/mega_rover/wheel_l/joint_states": "sensor_msgs/msg/JointState",
    "/mega_rover/wheel_r/joint_states": "sensor_msgs/msg/JointState",
    "/mega_rover/battery/battery_state": "sensor_msgs/msg/BatteryState",
}
pytestmark = [pytest.mark.avr, pytest.mark.slow]
if not ROS2_PY.exists():
    pytestmark.append(pytest.mark.skip(reason=f"ROS 2 wheels not installed ({ROS2_PY}; make ros2)"))


@pytest.fixture
def daemon(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[dict[str, str]]:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path_factory.getbasetemp() / "xdg-cache"))
    # (no world: the rig's own models turn the wheels and hold the pack at 7.4 V)
    with board_process("--file", str(ROVER), "--runtime", "avr", "--world", "none") as url:
        cfg = tmp_path / "robot.toml"
        # (the wheels' counts_per_rev come in their descriptors, from the board file)
        cfg.write_text(
            f'[daemon]\npublishers = ["bus", "ros2"]\n\n[[board]]\nurl = "{url}"\ntimeout = 2.0\n'
        )
        env = ros_env()
        p = subprocess.Popen(
            [str(ROS2_PY), "-m", "missing_link", "run", "--config", str(cfg), "--duration", "150"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
        )  # fmt: skip
        try:
            yield env
        finally:
            err = stop(p)
            assert "Traceback" not in err, err[-3000:]


def listen(env: dict[str, str], *args: str) -> dict[str, Any]:
    r = subprocess.run(
        [str(ROS2_PY), str(LISTENER), *args], capture_output=True, text=True, env=env, timeout=150
    )
    assert r.returncode == 0, r.stderr[-3000:]
    out: dict[str, Any] = json.loads(r.stdout.strip().splitlines()[-1])
    return out


def test_stock_rclpy_sees_the_rovers_imu_and_wheels_and_drives_its_motors(
    daemon: dict[str, str],
) -> None:
    half_turn = math.pi  # (radians: the JointState of a wheel, its counts_per_rev the board's)
    got = listen(
        daemon,
        *("--seconds", "120", "--min", "3"),
        *[x for topic, type_ in SUBS.items() for x in ("--sub", f"{topic}={type_}")],
        *("--float64", "/mega_rover/motor_l/command=0.5"),
        *("--float64", "/mega_rover/motor_r/command=0.5"),
        *("--until-moved", f"/mega_rover/wheel_l/joint_states=position={half_turn}"),
        *("--until-moved", f"/mega_rover/wheel_r/joint_states=position={half_turn}"),
    )
    assert got["held"], got["counts"]
    rx = got["received"]
    for topic, type_ in SUBS.items():
        assert got["topics"][topic] == [type_], topic
    for topic in ("/mega_rover/motor_l/command", "/mega_rover/motor_r/command"):
        assert got["topics"][topic] == ["std_msgs/msg/Float64"]
    for m in rx["/mega_rover/imu/imu"]:  # at rest, level: 1 g, in the board's frame
        a = m["linear_acceleration"]
        assert math.hypot(a["x"], a["y"], a["z"]) == pytest.approx(9.80665, abs=0.01)
        assert m["frame_id"] == "mega_rover/imu" and got["start_ns"] < m["stamp_ns"]
    assert rx["/mega_rover/imu/temperature"][-1]["temperature"] == pytest.approx(25.0, abs=0.01)
    # both wheels forward (the right one's bridge inverted, its count reversed: mirrored), a
    # speed while they turn: the Float64 drove the motors, the motors the rig's wheels
    for side in ("wheel_l", "wheel_r"):
        states = rx[f"/mega_rover/{side}/joint_states"]
        positions = [m["position"][0] for m in states]
        assert positions[-1] - min(positions) >= half_turn, side
        assert any(m["velocity"][0] > 0 for m in states if not math.isnan(m["velocity"][0]))
        assert states[-1]["name"] == [f"mega_rover/{side}"]
    b = rx["/mega_rover/battery/battery_state"][-1]
    assert b["voltage"] == pytest.approx(7.4, abs=0.03) and 0 < b["percentage"] < 1
