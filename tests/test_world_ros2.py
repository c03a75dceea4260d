"""Item 5 of issue 47, end to end against a node we did not write: the example rover runs as a
virtual board in its world (``missing-link board --file --world``, each runtime), the daemon
publishes it on ROS 2 (rclpy, Fast DDS on loopback), and a stock rclpy node
(tests/ros2_world_driver.py: rclpy and the message packages only) drives it with each wheel's
effort on /joint_commands (stamped ahead: both wheels act at one instant) and checks, from
what the daemon publishes: at rest the
accelerometer reads g; driving straight both wheels' JointState velocities agree and the gyro's
z stays near 0, the forward ranger's distance falls by what the wheels rolled (within its
resolution) and the GPS fix moves with the body; turning in place the gyro's z has REP-103's
sign and its integral is the compass's change of heading.  The node waits for events, never a
fixed time; the bounds are the parts' datasheet figures."""

from __future__ import annotations

import json
import math
import statistics
import subprocess
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from .test_board_file import BoardProcess
from .test_ros2 import ROS2_PY, ros_env, stop

ROOT = Path(__file__).resolve().parent.parent
ROVER = ROOT / "examples" / "boards" / "rover.py"
DRIVER = Path(__file__).with_name("ros2_world_driver.py")
RUNTIMES = ("cpython", pytest.param("micropython", marks=pytest.mark.micropython))
pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]
if not ROS2_PY.exists():
    pytestmark.append(pytest.mark.skip(reason=f"ROS 2 wheels not installed ({ROS2_PY}; make ros2)"))
#: 2 m from the room's centre towards +x: the HC-SR04 (4 m reach) sees the wall ahead from the
#: start; an RTK receiver (2 cm CEP), so that a metre's drive shows in the fix beyond its noise
WORLD = """
[start]
x_m = 2.0
[parts.gps]
cep_m = 0.02
"""
R = 0.033
G = 9.80665
#: one ddmm.mmmm step of NMEA's (1e-4 minute) at the default origin, metres east and north
NMEA_EAST, NMEA_NORTH = 1e-4 / 60 * 111_320 * math.cos(math.radians(48.1173)), 1e-4 / 60 * 111_200


def daemon_toml(url: str) -> str:
    return f"""
[daemon]
publishers = ["bus", "ros2"]
[[board]]
url = "{url}"
timeout = 2.0
[boards.rover.ros.wheel_l]
counts_per_rev = 400
[boards.rover.ros.wheel_r]
counts_per_rev = 400
[joints]
command_timeout = 1.0
[joints.left_wheel]
state = "rover/wheel_l"
command = "rover/motor_l"
[joints.right_wheel]
state = "rover/wheel_r"
command = "rover/motor_r"
"""


@pytest.fixture(params=RUNTIMES)
def driven(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[dict[str, Any]]:
    world = tmp_path / "world.toml"
    world.write_text(WORLD)
    board = BoardProcess(tmp_path, ROVER, request.param, "--world", str(world), "--seed", "3")
    cfg = tmp_path / "robot.toml"
    cfg.write_text(daemon_toml(board.url))
    env = ros_env()
    log = (tmp_path / "daemon.err").open("w")  # (kept with the samples: a failure's look)
    daemon = subprocess.Popen(
        [str(ROS2_PY), "-m", "missing_link", "run", "--config", str(cfg), "--duration", "300"],
        stdout=subprocess.PIPE, stderr=log, text=True, env=env,
    )  # fmt: skip
    try:
        dump = tmp_path / "samples.json"  # (kept where pytest keeps tmp_path: a failure's look)
        r = subprocess.run([str(ROS2_PY), str(DRIVER), "--seconds", "240", "--dump", str(dump)],
                           capture_output=True, text=True, env=env, timeout=300)  # fmt: skip
        assert r.returncode == 0, r.stderr[-3000:]
        yield json.loads(r.stdout.strip().splitlines()[-1])
    finally:
        stop(daemon)
        log.close()
        board.close()
        err = (tmp_path / "daemon.err").read_text()
        assert "Traceback" not in err, err[-3000:]
    assert board.proc.returncode == 0, board.stderr()


def test_a_stock_rclpy_node_drives_the_rover_in_its_world(driven: dict[str, Any]) -> None:
    rest, straight, turn = driven["rest"], driven["straight"], driven["turn"]
    # at rest: g, up (50 samples: the mean's noise is 0.026 / sqrt(50) m/s^2)
    assert rest["accel_norm"] == pytest.approx(G, abs=0.015)
    assert rest["accel_mean"][2] == pytest.approx(G, abs=0.015)
    # straight: both wheels as fast as each other, no turn
    pairs = straight["velocity_pairs"]
    assert len(pairs) >= 10
    # (a sample's velocity is its counts over the time between its stamp and the last one's:
    # the two wheels' samples of one instant share that time, so their ratio is the check)
    ratios = [b / a for a, b, _t in pairs if a > 0 and b > 0]
    assert len(ratios) >= 10 and statistics.median(ratios) == pytest.approx(1, abs=0.02), pairs
    agree = [abs(a - b) <= 0.1 * max(abs(a), abs(b)) for a, b, _t in pairs]
    assert sum(agree) >= 0.8 * len(pairs), pairs
    gz = straight["gyro_z"]
    # (rad/s; the noise 0.00057 a sample; the bridges' ramps, each motor's own, end a few ms
    # apart: a turn of a fraction of a degree a second while they do)
    assert len(gz) >= 20 and abs(statistics.fmean(gz)) < 0.002, gz
    assert max(abs(z) for z in gz) < 0.02, gz
    # the ranger ahead came nearer by what the wheels rolled
    rolled = R * statistics.fmean(
        b - a for a, b in zip(rest["wheels_rad"], straight["wheels_rad"], strict=True)
    )
    fell = rest["range_m"] - straight["range_m"]
    noise = 3 * 0.003 / math.sqrt(10)  # (HC-SR04: 3 mm a sample, ten averaged at each end)
    assert fell == pytest.approx(rolled, abs=straight["resolution_m"] + noise)
    # the fix moved with the body: east (it faces +x), by what it rolled
    (lat0, lon0), (lat1, lon1) = rest["fix"], straight["fix"]
    east = (lon1 - lon0) * 111_320 * math.cos(math.radians(lat0))
    north = (lat1 - lat0) * 111_200
    assert east == pytest.approx(rolled, abs=NMEA_EAST + 0.08)
    assert north == pytest.approx(0.0, abs=NMEA_NORTH + 0.08)
    # turning in place: counter-clockwise is positive (REP-103), and the gyro's integral is the
    # compass's change of heading (the field turns the other way in the body's axes)
    assert turn["gyro_z_max"] > 1.0 and turn["gyro_z_min"] > -0.005
    assert math.degrees(turn["gyro_integral"]) >= 90
    # (the world holds a reading for its tick, 10 ms: at the turn's start and end the gyro's
    # samples may be that late, 2 x 10 ms x the fastest rate; the trapezoids, where the rate
    # changed between two samples; a board held up (a busy machine: the simulator moves the
    # world between the firmware's steps only) reads a stale world, as late as its longest gap
    # between two samples, once at the start and once at the end; the compass's 2 mG of
    # 0.21 G horizontal field, at the first and the last sample: 0.8 degree)
    late = 2 * max(0.010, turn["imu_gap_s"] - 0.020) * turn["gyro_z_max"]  # (50 Hz: 20 ms)
    bound = math.degrees(late + turn["gyro_gaps"]) + 0.8
    assert math.degrees(turn["compass_turn"]) == pytest.approx(
        math.degrees(turn["gyro_integral"]), abs=bound
    )
