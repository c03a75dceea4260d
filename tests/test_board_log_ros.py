"""The board's log on the ROS graphs (issue 36.2): the rover board file with its VL53L0X absent
logs one WARN naming ``tof``, which an rclpy node that imports nothing of ours hears on
``/rosout`` (ROS 2 from the Kilted wheels, the daemon in `.venv-ros2`); and a rospy node (Debian's
ROS 1) hears a board's fault on ``/rosout`` as ``rosgraph_msgs/Log``.  Skipped, with the reason,
where ROS 2 or ROS 1 is not installed (test_ros2.py and test_ros1.py say how)."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

from .helpers import FirmwareSim, board_process
from .test_board_log import probe_board
from .test_ros1 import HAVE_ROS1, roscore
from .test_ros2 import ROS2_PY, listen, ros_env, start_daemon, stop

ROOT = Path(__file__).resolve().parent.parent
ROVER = ROOT / "examples" / "boards" / "rover.py"
#: how the rover with its VL53L0X absent is made: "sim" (the MicroPython simulator, the part
#: taken out of its world and the board rebooted: absent from boot) until `missing-link board
#: --file F --absent tof` lands; then "cli"
ABSENT_BY = "sim"


@contextmanager
def rover_without_tof() -> Iterator[str]:
    """The rover board file with its VL53L0X absent, as a board URL."""
    if ABSENT_BY == "cli":
        with board_process("--file", str(ROVER), "--absent", "tof") as url:
            yield url
        return
    sim = FirmwareSim(ROVER)
    try:
        sim.ctl("del WORLD.i2c[(0, 0x29)]; reboot()")  # (no acknowledge at 0x29 from now on)
        yield sim.url
    finally:
        sim.close()


@pytest.mark.slow
@pytest.mark.micropython
@pytest.mark.skipif(not ROS2_PY.exists(), reason=f"ROS 2 wheels not installed ({ROS2_PY})")
def test_an_absent_vl53l0x_is_one_warn_naming_tof_on_rosout() -> None:
    env = ros_env()
    with rover_without_tof() as url:
        daemon = start_daemon(url, env)
        try:
            got = listen(
                env,
                *("--seconds", "60", "--min", "1", "--transient-local", "--depth", "100"),
                *("--sub", "/rosout=rcl_interfaces/msg/Log", "--until-text", "/rosout=tof"),
            )
            time.sleep(1.0)  # (a second line, were there one, would be there by now)
            again = listen(
                env,
                *("--seconds", "10", "--min", "1", "--transient-local", "--depth", "100"),
                *("--sub", "/rosout=rcl_interfaces/msg/Log"),
            )
        finally:
            err = stop(daemon)
    for heard in (got, again):  # (the second: a late joiner gets it from the history)
        received = heard["received"]
        assert isinstance(received, dict)
        rover = [m for m in received["/rosout"] if m["name"] == "rover"]
        (line,) = [m for m in rover if "tof" in m["msg"]]
        assert line["level"] == 30 and line["function"] == "tof"  # WARN
        assert line["msg"].startswith("tof: not answering"), line
    assert "[rover] WARN tof: not answering" in err  # the console line, on stderr


@pytest.mark.slow
@pytest.mark.skipif(not HAVE_ROS1, reason="ROS 1 not installed (scripts/system-deps.sh --ros1)")
def test_rospy_hears_a_board_fault_on_rosout(serve: Any, tmp_path: Path) -> None:
    rt, probe = probe_board()
    server = serve(rt, "tcp://127.0.0.1:0")
    daemon = listener = None
    with roscore(tmp_path) as env:
        try:
            daemon = subprocess.Popen(
                [sys.executable, "-m", "missing_link", "run", server.url, "-p", "ros1",
                 "--duration", "60"],
                env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
            )  # fmt: skip
            listener = subprocess.Popen(
                ["/usr/bin/python3", "-c", ROSPY_ROSOUT, "probe_board"],
                env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
            )  # fmt: skip
            assert listener.stdout is not None
            assert listener.stdout.readline().strip() == "READY"  # matched the daemon's /rosout
            probe.absent = True
            out, err = listener.communicate(timeout=60)
        finally:
            for p in (listener, daemon):
                if p is not None and p.poll() is None:
                    p.terminate()
                    p.wait(10)
    assert listener.returncode == 0, err
    msg = json.loads(out.strip().splitlines()[-1])
    assert msg["level"] == 4 and msg["function"] == "probe"  # rosgraph_msgs/Log WARN
    # (live, or from the board's counts when it said it before the daemon was there)
    assert msg["msg"].startswith("probe: not answering")
    assert abs(msg["stamp_ns"] - time.time_ns()) < 60 * 10**9


#: an independent rospy node (Debian's system Python, nothing of ours): prints READY once its
#: /rosout subscription is connected to the daemon, then the first line of the board named on
#: its command line as JSON
ROSPY_ROSOUT = """
import json, sys, threading, time
import rosgraph, rospy
from rosgraph_msgs.msg import Log
rospy.init_node("independent_rosout_listener", disable_signals=True)
done = threading.Event()
def on(m):
    if m.name == sys.argv[1] and not done.is_set():
        print(json.dumps({"level": m.level, "msg": m.msg, "function": m.function,
                          "stamp_ns": m.header.stamp.to_nsec()}), flush=True)
        done.set()
sub = rospy.Subscriber("/rosout", Log, on)
master = rosgraph.Master(rospy.get_name())
def others():  # the nodes that publish /rosout, this one aside
    pubs = dict(master.getSystemState()[0]).get("/rosout", [])
    return [n for n in pubs if n != rospy.get_name()] if "/missing_link" in pubs else None
deadline = time.monotonic() + 40
while time.monotonic() < deadline:
    nodes = others()
    if nodes is not None and sub.get_num_connections() >= len(nodes):
        break
    time.sleep(0.1)
print("READY", flush=True)
sys.exit(0 if done.wait(40) else 1)
"""
