"""The standard types on every face, read by consumers we did not write: ROS 2 through Zenoh in
rmw_zenoh's format (a plain zenoh + rosbags process checks every key's RIHS01 type hash and
sends Float64 and JointState commands), MCAP (read back with rosbags and with the mcap library's
own reader: the schemas Foxglove's panels use), Foxglove live (the official protocol client
parses each advertised schema), and ROS 1 (Debian's rospy with its installed classes).  The
boards are the rig, the rover and a battery board as virtual boards (tests/standard_boards.py).
(rclpy: tests/test_standard_ros2.py.)"""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from missing_link.daemon import Daemon
from missing_link.daemon.config import parse_config

from .helpers import ML, FirmwareSim, free_port, wait_for
from .standard_boards import boards as boards  # (a fixture)
from .standard_boards import daemon_toml
from .test_ros1 import HAVE_ROS1, roscore

HERE = Path(__file__).resolve().parent
STORE = get_typestore(Stores.ROS2_JAZZY)
pytestmark = [pytest.mark.micropython, pytest.mark.slow]
STANDARD = {
    "/rig/imu/imu": "sensor_msgs/msg/Imu",
    "/rig/imu/temperature": "sensor_msgs/msg/Temperature",
    "/rig/dist_ir/range": "sensor_msgs/msg/Range",
    "/rover/tof/range": "sensor_msgs/msg/Range",
    "/rover/wheel_l/joint_states": "sensor_msgs/msg/JointState",
    "/rover/compass/field": "sensor_msgs/msg/MagneticField",
    "/rover/gps/fix": "sensor_msgs/msg/NavSatFix",
    "/rover/gps/time_reference": "sensor_msgs/msg/TimeReference",
    "/power/battery/battery_state": "sensor_msgs/msg/BatteryState",
    "/power/bumper/active": "std_msgs/msg/Bool",
}


def robot(boards: dict[str, FirmwareSim], publishers: str, tables: str = "") -> Daemon:
    urls = (boards["rig"].url, boards["rover"].url, boards["power"].url)
    return Daemon(parse_config(tomllib.loads(daemon_toml(*urls, publishers=publishers) + tables)))


def test_zenoh_consumer_decodes_standard_types_by_their_type_hash_and_commands(
    boards: dict[str, FirmwareSim],
) -> None:
    port = free_port()
    tables = f'\n[zenoh]\nlisten = ["tcp/127.0.0.1:{port}"]\nconnect = []\n'
    with robot(boards, '["bus", "zenoh"]', tables) as d:
        assert d.wait_until_up(60), d.failures()
        r = subprocess.run(
            [sys.executable, str(HERE / "zenoh_standard_listener.py"),
             "--connect", f"tcp/127.0.0.1:{port}", "--seconds", "8",
             "--float64", "/rig/servo/command=0.5", "--joint", f"mast=position={math.pi}"],
            capture_output=True, text=True, timeout=90,
        )  # fmt: skip
        assert r.returncode == 0, r.stderr[-3000:]
        mast = "result = WORLD.devices['mast'].position"
        assert wait_for(lambda: boards["rover"].ctl(mast) == 800, 10)  # the JointState command
        d.bus.send("/joint_commands", {"name": ["mast"], "position": [0.0]})
        assert wait_for(lambda: boards["rover"].ctl(mast) == 0, 10)
    topics = json.loads(r.stdout.strip().splitlines()[-1])["topics"]
    for topic, type_name in STANDARD.items():
        assert topics[topic]["type"] == type_name and topics[topic]["hash_ok"], topic
        assert topics[topic]["messages"], topic
    for m in topics["/rig/imu/imu"]["messages"]:
        a = m["linear_acceleration"]
        assert math.hypot(a["x"], a["y"], a["z"]) == pytest.approx(9.81, abs=0.01)
        assert m["source_ns"] == m["stamp_ns"]  # the attachment's time: the measurement's
    assert boards["rig"].ctl("result = WORLD.pulse_us(15)") == round(1500 + 40 * 600 / 127)


def test_mcap_holds_the_standard_schemas_and_reads_back(
    boards: dict[str, FirmwareSim], tmp_path: Path
) -> None:
    tables = f'\n[mcap]\npath = "{tmp_path}"\nchunk_s = 0.2\n'
    with robot(boards, '["bus", "mcap"]', tables) as d:
        assert d.wait_until_up(60), d.failures()
        d.bus.send("/joint_commands", {"name": ["pan"], "position": [0.25]})
        recorded = next(p for p in d.publishers if p.name == "mcap")
        assert wait_for(lambda: all(recorded.messages_by_topic.get(t) for t in STANDARD), 15)  # type: ignore[attr-defined]
        bags = list(recorded.bags)  # type: ignore[attr-defined]
    with AnyReader(bags, default_typestore=STORE) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        assert STANDARD.items() <= types.items()
        assert types["/joint_states"] == "sensor_msgs/msg/JointState"
        imu = [c for c in reader.connections if c.topic == "/rig/imu/imu"]
        for conn, log_ns, raw in reader.messages(connections=imu):
            m = reader.deserialize(raw, conn.msgtype)
            assert m.header.stamp.sec * 10**9 + m.header.stamp.nanosec == log_ns
            a = m.linear_acceleration
            assert math.hypot(a.x, a.y, a.z) == pytest.approx(9.81, abs=0.01)
    (mcap_file,) = bags[0].glob("*.mcap")
    with open(mcap_file, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    schemas = {s.name: s for s in summary.schemas.values()}
    for type_name in set(STANDARD.values()):  # every schema with its dependencies, ros2msg
        assert schemas[type_name].encoding == "ros2msg" and schemas[type_name].data, type_name
    assert b"MSG: geometry_msgs/Vector3" in schemas["sensor_msgs/msg/Imu"].data
    channels = {c.topic: c for c in summary.channels.values()}
    assert all(channels[t].message_encoding == "cdr" for t in STANDARD)


def test_foxglove_decodes_the_standard_types_with_their_advertised_schemas(
    boards: dict[str, FirmwareSim],
) -> None:
    node = shutil.which("node")
    assert node, "node is installed by make test (scripts/system-deps.sh)"
    with robot(boards, '["bus", "foxglove"]', "\n[foxglove]\nport = 0\n") as d:
        assert d.wait_until_up(60), d.failures()
        fox = next(p for p in d.publishers if p.name == "foxglove")
        r = subprocess.run(
            [node, str(HERE / "foxglove_standard_client.mjs"), fox.url, *STANDARD],  # type: ignore[attr-defined]
            capture_output=True, text=True, timeout=60, cwd=HERE.parent,
        )  # fmt: skip
    assert r.returncode == 0, r.stderr[-3000:]
    out = json.loads(r.stdout.strip().splitlines()[-1])
    for topic, type_name in STANDARD.items():
        assert out[topic]["schemaName"] == type_name and out[topic]["encoding"] == "cdr"
        assert out[topic]["schemaEncoding"] == "ros2msg"
    imu = out["/rig/imu/imu"]["message"]
    a = imu["linear_acceleration"]
    assert math.hypot(a["x"], a["y"], a["z"]) == pytest.approx(9.81, abs=0.01)
    stamp = imu["header"]["stamp"]
    assert stamp["sec"] * 10**9 + stamp["nanosec"] == int(out["/rig/imu/imu"]["log_time_ns"])
    assert out["/rover/tof/range"]["message"]["range"] == pytest.approx(0.5)
    assert out["/power/battery/battery_state"]["message"]["voltage"] == pytest.approx(7.4, abs=0.01)


@pytest.mark.skipif(not HAVE_ROS1, reason="ROS 1 not installed (scripts/system-deps.sh --ros1)")
def test_rospy_gets_the_standard_types_and_commands_with_float64(
    boards: dict[str, FirmwareSim], tmp_path: Path
) -> None:
    cfg = tmp_path / "robot.toml"
    urls = (boards["rig"].url, boards["rover"].url, boards["power"].url)
    cfg.write_text(daemon_toml(*urls, publishers='["bus", "ros1"]'))
    daemon = None
    with roscore(tmp_path) as env:
        try:
            daemon = subprocess.Popen(
                [*ML, "run", "--config", str(cfg), "--duration", "60"],
                env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
            )  # fmt: skip
            subs = {**{t: ty.replace("/msg/", "/") for t, ty in STANDARD.items()},
                    "/rig/servo/joint_states": "sensor_msgs/JointState"}  # fmt: skip
            r = subprocess.run(
                ["/usr/bin/python3", str(HERE / "ros1_standard_listener.py"),
                 *[x for t, ty in subs.items() for x in ("--sub", f"{t}={ty}")],
                 "--float64", "/rig/servo/command=0.5", "--timeout", "50"],
                env=env, capture_output=True, text=True, timeout=90,
            )  # fmt: skip
        finally:
            if daemon is not None:
                daemon.terminate()
                err = daemon.communicate(timeout=15)[1]
                assert "Traceback" not in err, err[-3000:]
    assert r.returncode == 0, r.stderr[-3000:]
    got: dict[str, list[dict[str, Any]]] = json.loads(r.stdout.strip().splitlines()[-1])["received"]
    assert all(got[t] for t in subs), {t: len(v) for t, v in got.items()}
    a = got["/rig/imu/imu"][-1]["linear_acceleration"]
    assert math.hypot(a["x"], a["y"], a["z"]) == pytest.approx(9.81, abs=0.01)
    assert got["/rig/imu/imu"][-1]["frame_id"] == "rig/imu"
    for m in got["/rig/imu/imu"]:
        assert m["stamp_ns"] <= m["recv_ns"]
    wheel = got["/rover/wheel_l/joint_states"][-1]
    assert wheel["name"] == ["rover/wheel_l"] and wheel["frame_id"] == "left_wheel_link"
    assert (
        abs(got["/rig/servo/joint_states"][-1]["position"][0] - 0.5) <= math.radians(0.708661) / 2
    )
    assert got["/power/battery/battery_state"][-1]["voltage"] == pytest.approx(7.4, abs=0.01)
    ref = got["/rover/gps/time_reference"][-1]  # a PPS edge's UTC: a whole second
    assert ref["time_ref"] % 10**9 == 0 and ref["source"] == "gps", ref
