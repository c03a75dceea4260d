"""ROS 1: a real roscore on 127.0.0.1, the daemon (``missing-link run -p ros1``) in its own
process, and an independent rospy subscriber (Debian's system Python) receiving a thesis-format
type generated at runtime and a standard sensor_msgs/Range.

Needs Debian's ros-core (``scripts/system-deps.sh --ros1``; ``.ci/run`` does it).  Without it the
test is skipped, unless ML_REQUIRE_ROS1=1 (set by ``.ci/run``) makes that a failure.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from missing_link.virtual.process import start_board_process, stop_process

from .helpers import ML, free_port, wait_for

pytestmark = [pytest.mark.slow]  # (every test here starts a process: make check skips them)

HERE = Path(__file__).resolve().parent
HAVE_ROS1 = shutil.which("roscore") is not None and Path("/usr/bin/python3").exists()

if not HAVE_ROS1:
    if os.environ.get("ML_REQUIRE_ROS1") == "1":
        raise RuntimeError(
            "ML_REQUIRE_ROS1=1 but roscore is missing: scripts/system-deps.sh --ros1"
        )
    pytestmark += [pytest.mark.skip(reason="ROS 1 not installed (scripts/system-deps.sh --ros1)")]


@contextmanager
def roscore(tmp_path: Path) -> Iterator[dict[str, str]]:
    """A real roscore on a free 127.0.0.1 port, up (within 20 s: a bound on a hang), stopped
    after; yields the ROS environment that finds it."""
    port = free_port()
    env = {
        **os.environ,
        "ROS_MASTER_URI": f"http://127.0.0.1:{port}",
        "ROS_IP": "127.0.0.1",
        "ROS_HOME": str(tmp_path / "ros"),
    }
    core = subprocess.Popen(
        ["roscore", "-p", str(port)], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    try:
        online = "import rosgraph,sys; sys.exit(0 if rosgraph.is_master_online() else 1)"

        def up() -> bool:
            return subprocess.run(["/usr/bin/python3", "-c", online], env=env).returncode == 0

        assert wait_for(up, 20, step=0.3), "roscore did not come up"
        yield env
    finally:
        core.terminate()
        core.wait(15)


@contextmanager
def ros1_graph(tmp_path: Path, sim: str) -> Iterator[tuple[dict[str, str], str]]:
    """A real roscore on a free 127.0.0.1 port, a virtual board process (sim) over a pty, and the
    daemon (``run -p ros1``) in its own process; yields the ROS environment and the board URL."""
    with roscore(tmp_path) as env:
        board, url = start_board_process(sim, 0, "pty")
        daemon = None
        try:
            daemon = subprocess.Popen(
                [*ML, "run", url, "-p", "ros1", "--duration", "40"],
                env=env,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.PIPE,
                text=True,
            )
            yield env, url
        finally:
            if daemon is not None:
                daemon.terminate()
                daemon.wait(10)
            stop_process(board)


def listen(env: dict[str, str], *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        ["/usr/bin/python3", str(HERE / "ros1_listener.py"), *args],
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
    )


def test_real_rospy_subscriber_receives(tmp_path: Path) -> None:
    with ros1_graph(tmp_path, "rangers") as (env, _url):
        out = listen(
            env,
            "--custom",
            "/board_b/dist_ir=missing_link_msgs/DistIr=time[] times\\nuint16[] values",
            "--range",
            "/board_b/dist_ir/range",
            "--count",
            "5",
        )
    assert out.returncode == 0, out.stdout + out.stderr
    lines = [json.loads(x) for x in out.stdout.splitlines()]
    custom = [x for x in lines if x["topic"] == "/board_b/dist_ir"]
    ranges = [x for x in lines if x["topic"] == "/board_b/dist_ir/range"]
    assert len(custom) == 5 and len(ranges) == 5
    assert all(len(x["values"]) == 8 for x in custom)
    assert any(s > 1_600_000_000 for x in custom for s in x["secs"])  # synchronised host time
    assert all(0.2 <= r["range"] <= 1.5 and r["type"] == 1 for r in ranges)  # metres, INFRARED
    assert all(r["frame"].startswith("board_b/dist_ir/") for r in ranges)


def test_ros1_node_drives_the_servo(tmp_path: Path) -> None:
    """A real rospy node publishes on /board_a/servo/cmd; the board's servo moves, and the
    daemon's /board_a/servo topic says so (ROS 1 actuators go the same latest-wins path)."""
    with ros1_graph(tmp_path, "encoder_servo") as (env, _url):
        out = listen(
            env,
            "--custom",
            "/board_a/servo=missing_link_msgs/Servo=time[] times\\nint8[] values",
            "--command",
            "/board_a/servo/cmd=40",
            "--expect",
            "40",
        )
        time.sleep(1.0)  # settled: the servo's state goes out no more
        late = listen(  # a node that starts now gets the current state: the topic is latched
            env,
            "--custom",
            "/board_a/servo=missing_link_msgs/Servo=time[] times\\nint8[] values",
            *("--expect", "40", "--timeout", "15"),
        )
    assert out.returncode == 0, out.stdout + out.stderr
    (line,) = [json.loads(x) for x in out.stdout.splitlines()]
    assert line["topic"] == "/board_a/servo" and 40 in line["values"]
    assert late.returncode == 0, late.stdout + late.stderr
    assert 40 in json.loads(late.stdout.splitlines()[0])["values"]
