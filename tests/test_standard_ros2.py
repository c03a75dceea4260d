"""Standard types on real ROS 2 (rclpy + rmw_fastrtps_cpp from the Kilted wheels), heard by a
node that imports nothing of ours (tests/ros2_standard_listener.py): the rover, the thesis rig
and a battery board run as virtual boards (tests/standard_boards.py), the daemon runs
``missing-link run --config`` in .venv-ros2, and the node lists the topics with their types,
subscribes by standard type and checks the physics: an IMU at rest reads 1 g, a range lies in
its limits in metres, an encoder's joint moves by the radians it turned, every stamp lies
between the node's start and its receipt of the message; its Float64 moves the servo and its
JointState command moves the rover's mast (ros2_control's topic-based interface in its message
format: controller_manager is not available as wheels, so the contract is what is tested).
Loopback only (tests/fastdds_loopback.xml)."""

from __future__ import annotations

import json
import math
import subprocess
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from .helpers import FirmwareSim
from .standard_boards import COUNTS_PER_REV, daemon_toml
from .standard_boards import boards as boards  # (a fixture)
from .test_ros2 import ROS2_PY, ros_env, stop

LISTENER = Path(__file__).with_name("ros2_standard_listener.py")
PARAMS = Path(__file__).with_name("ros2_param_client.py")
pytestmark = [pytest.mark.micropython, pytest.mark.slow]
if not ROS2_PY.exists():
    pytestmark.append(pytest.mark.skip(reason=f"ROS 2 wheels not installed ({ROS2_PY}; make ros2)"))
SUBS = {
    "/rig/imu/imu": "sensor_msgs/msg/Imu",
    "/rig/imu/temperature": "sensor_msgs/msg/Temperature",
    "/rig/dist_ir/range": "sensor_msgs/msg/Range",
    "/rover/tof/range": "sensor_msgs/msg/Range",
    "/rover/sonar/range": "sensor_msgs/msg/Range",
    "/rover/wheel_l/joint_states": "sensor_msgs/msg/JointState",
    "/rover/compass/field": "sensor_msgs/msg/MagneticField",
    "/rover/gps/fix": "sensor_msgs/msg/NavSatFix",
    "/power/battery/battery_state": "sensor_msgs/msg/BatteryState",
    "/power/bumper/active": "std_msgs/msg/Bool",
    "/rig/servo/joint_states": "sensor_msgs/msg/JointState",
    "/joint_states": "sensor_msgs/msg/JointState",
}
SERVO_LSB = math.radians(0.708661)


@pytest.fixture
def daemon(boards: dict[str, FirmwareSim], tmp_path: Path) -> Iterator[dict[str, str]]:
    cfg = tmp_path / "robot.toml"
    urls = (boards["rig"].url, boards["rover"].url, boards["power"].url)
    cfg.write_text(daemon_toml(*urls, publishers='["bus", "ros2"]'))
    env = ros_env()
    p = subprocess.Popen(
        [str(ROS2_PY), "-m", "missing_link", "run", "--config", str(cfg), "--duration", "120"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        yield env
    finally:
        err = stop(p)
        assert "Traceback" not in err, err[-3000:]


def listen(env: dict[str, str], *args: str, timeout: float = 120) -> dict[str, Any]:
    r = subprocess.run(
        [str(ROS2_PY), str(LISTENER), *args], capture_output=True, text=True, env=env,
        timeout=timeout,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr[-3000:]
    out: dict[str, Any] = json.loads(r.stdout.strip().splitlines()[-1])
    return out


def test_stock_rclpy_reads_every_standard_type_and_its_physics(
    boards: dict[str, FirmwareSim], daemon: dict[str, str]
) -> None:
    quarter = 2 * math.pi * 100 / COUNTS_PER_REV
    turning = threading.Event()

    def turn() -> None:  # the rover's left wheel turns a quarter while the node listens
        turning.wait(120)
        for _ in range(10):
            boards["rover"].ctl("WORLD.encoder_steps(2, 3, 10)")
            time.sleep(0.05)

    wheel = threading.Thread(target=turn, daemon=True)
    wheel.start()
    boards["power"].ctl("WORLD.bounce(14, 0)")  # the bumper is pressed (its heartbeat says so)
    threading.Timer(8.0, turning.set).start()  # (after the node has matched its topics)
    got = listen(
        daemon,
        *("--seconds", "90", "--min", "3"),
        *[x for topic, type_ in SUBS.items() for x in ("--sub", f"{topic}={type_}")],
        *("--float64", "/rig/servo/command=0.5"),
        *("--joint", f"mast=position={math.pi}"),
        *("--until-near", f"/rig/servo/joint_states=position=0.5={SERVO_LSB / 2}"),
        *("--until-near", f"/joint_states=position={math.pi}=1e-6"),
        *("--until-moved", f"/rover/wheel_l/joint_states=position={quarter - 1e-9}"),
    )
    turning.set()
    wheel.join(10)
    boards["power"].ctl("WORLD.bounce(14, 1)")
    assert got["held"], {k: v for k, v in got["counts"].items()}
    rx = got["received"]
    # the graph lists every topic with its standard type
    for topic, type_ in SUBS.items():
        assert got["topics"][topic] == [type_], topic
    assert got["topics"]["/rig/servo/command"] == ["std_msgs/msg/Float64"]
    assert got["topics"]["/joint_commands"] == ["sensor_msgs/msg/JointState"]
    # every stamp: the board's measurement in host time, after the node started and before
    # the node had it (the daemon never stamps a sample later than its arrival)
    for topic in SUBS:
        if topic in ("/power/bumper/active",):
            continue  # (std_msgs/Bool has no header)
        for m in rx[topic]:
            assert got["start_ns"] < m["stamp_ns"] <= m["recv_ns"], (topic, m)
    for m in rx["/rig/imu/imu"]:
        a = m["linear_acceleration"]
        assert math.hypot(a["x"], a["y"], a["z"]) == pytest.approx(9.81, abs=0.01)
        assert m["orientation_covariance"][0] == -1 and m["frame_id"] == "rig/imu"
        assert m["linear_acceleration_covariance"][0] > 0
    for topic in ("/rig/dist_ir/range", "/rover/tof/range", "/rover/sonar/range"):
        for m in rx[topic]:
            assert m["min_range"] <= m["range"] <= m["max_range"], (topic, m)
    assert rx["/rover/sonar/range"][-1]["range"] == pytest.approx(1.0, abs=0.002)  # metres
    assert rx["/rover/sonar/range"][-1]["radiation_type"] == 0  # ULTRASOUND
    # the encoder's joint moved by exactly the radians it turned, with a speed while it did
    wheel_l = rx["/rover/wheel_l/joint_states"]
    positions = [m["position"][0] for m in wheel_l]
    assert max(positions) - min(positions) == pytest.approx(quarter)
    assert any(m["velocity"][0] > 0 for m in wheel_l if not math.isnan(m["velocity"][0]))
    assert wheel_l[-1]["name"] == ["rover/wheel_l"] and wheel_l[-1]["frame_id"] == "left_wheel_link"
    # the Float64 moved the servo: its JointState says where, in radians
    assert abs(rx["/rig/servo/joint_states"][-1]["position"][0] - 0.5) <= SERVO_LSB / 2
    assert boards["rig"].ctl("result = WORLD.pulse_us(15)") == round(1500 + 40 * 600 / 127)
    # the JointState command moved the mast, and /joint_states says so
    mast = [m for m in rx["/joint_states"] if m["name"] == ["mast"]]
    assert mast and mast[-1]["position"][0] == pytest.approx(math.pi)
    assert boards["rover"].ctl("result = WORLD.devices['mast'].position") == 800
    # and the rest: a battery, a bumper, a compass, a fix
    b = rx["/power/battery/battery_state"][-1]
    assert b["voltage"] == pytest.approx(7.4, abs=0.01) and 0 < b["percentage"] < 1
    assert any(m["data"] is True for m in rx["/power/bumper/active"])
    f = rx["/rover/compass/field"][-1]["magnetic_field"]
    assert (f["x"], f["y"], f["z"]) == (
        pytest.approx(2e-5),
        pytest.approx(-1e-5),
        pytest.approx(4e-5),
    )
    fix = rx["/rover/gps/fix"][-1]
    assert (fix["latitude"], fix["longitude"]) == (pytest.approx(48.1173), pytest.approx(11.516667))
    boards["rover"].ctl("pass")  # (the board is still there)


def test_frame_id_is_a_ros2_parameter(daemon: dict[str, str]) -> None:
    r = subprocess.run(
        [str(ROS2_PY), str(PARAMS), "--prefix", "rig.imu.",
         "--set", "rig.imu.frame_id=string:imu_link"],
        capture_output=True, text=True, env=daemon, timeout=90,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr[-3000:]
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert "rig.imu.frame_id" in out["names"] and out["results"][0]["successful"], out
    got = listen(daemon, "--seconds", "30", "--sub", "/rig/imu/imu=sensor_msgs/msg/Imu")
    frames = {m["frame_id"] for m in got["received"]["/rig/imu/imu"]}
    assert frames == {"imu_link"}, (out, frames)
