"""A GPS's TimeReference on real ROS 2 (issue 35.2): the rover's board file under the real
MicroPython (node), its GPS receiver simulated (NMEA with RMC's date, a PPS edge at the top of
each second), the daemon (``missing-link run -p ros2`` in .venv-ros2) and a stock rclpy node
that imports nothing of ours (tests/ros2_standard_listener.py).  Each TimeReference's
``time_ref`` is the simulated UTC second of a PPS edge and its ``header.stamp`` that edge in host
time: the board's stamp of the edge through clock sync, compared with the edge's time as the
test pairs the board's clock with the host's through the simulator's control channel."""

from __future__ import annotations

import json
import subprocess
import time
from pathlib import Path
from typing import Any

import pytest

from .helpers import FirmwareSim
from .standard_boards import ROVER
from .test_ros2 import ROS2_PY, ros_env, start_daemon, stop

LISTENER = Path(__file__).with_name("ros2_standard_listener.py")
pytestmark = [pytest.mark.micropython, pytest.mark.slow]
if not ROS2_PY.exists():
    pytestmark.append(pytest.mark.skip(reason=f"ROS 2 wheels not installed ({ROS2_PY}; make ros2)"))
REF = "/rover/gps/time_reference"
FIX = "/rover/gps/fix"
#: what the host time of an edge may differ by beyond the pairing's own window: the WebAssembly
#: port's clock counts whole ms (clock.res_us 1000), once in the board's stamp of the edge, once
#: in the pairing's read of the clock, once in clock sync's estimate (bounded by it)
RES_NS = 1_000_000


def listen(env: dict[str, str], *args: str) -> dict[str, Any]:
    r = subprocess.run(
        [str(ROS2_PY), str(LISTENER), *args], capture_output=True, text=True, env=env, timeout=120
    )
    assert r.returncode == 0, r.stderr[-3000:]
    out: dict[str, Any] = json.loads(r.stdout.strip().splitlines()[-1])
    return out


def edges_in_host_time(sim: FirmwareSim) -> tuple[dict[int, float], float]:
    """The simulated receiver's newest PPS edges: UTC second -> host time (CLOCK_REALTIME ns)
    at the middle of the pairing window; and that window's half width (ns).  The narrowest of
    ten pairings (the board's clock read between two reads of the host's), as NTP keeps its
    lowest-delay exchange."""
    code = (
        "import time; g = WORLD.devices['gps']; c = rt.clock(); n = time.ticks_us(); "
        "result = (c, [(c + time.ticks_diff(t, n), u) for t, u in g.edges])"
    )
    best: tuple[int, int, int, list[tuple[int, int]]] | None = None
    for _ in range(10):
        t1 = time.time_ns()
        board_now, edges = sim.ctl(code)
        t2 = time.time_ns()
        if best is None or t2 - t1 < best[1] - best[0]:
            best = (t1, t2, board_now, edges)
    assert best is not None
    t1, t2, board_now, edges = best
    mid = (t1 + t2) / 2
    return {utc: mid - (board_now - at) * 1000 for at, utc in edges}, (t2 - t1) / 2


def test_stock_rclpy_hears_the_utc_of_each_pps_edge_at_that_edge() -> None:
    sim = FirmwareSim(ROVER)
    env = ros_env()
    daemon = start_daemon(sim.url, env)
    try:
        got = listen(
            env, "--seconds", "60", "--min", "4",
            "--sub", f"{REF}=sensor_msgs/msg/TimeReference",
            "--sub", f"{FIX}=sensor_msgs/msg/NavSatFix",
        )  # fmt: skip
        edges, window = edges_in_host_time(sim)
    finally:
        err = stop(daemon)
        sim.close()
    assert "Traceback" not in err, err[-3000:]
    assert got["held"], got["counts"]
    assert got["topics"][REF] == ["sensor_msgs/msg/TimeReference"]
    refs, fixes = got["received"][REF], got["received"][FIX]
    fix_stamps = {m["stamp_ns"] for m in fixes}
    checked = 0
    for m in refs:
        utc_s, frac = divmod(m["time_ref"], 10**9)
        assert frac == 0 and m["source"] == "gps" and m["frame_id"] == "rover/gps", m
        assert got["start_ns"] < m["stamp_ns"] <= m["recv_ns"], m
        assert m["stamp_ns"] in fix_stamps  # the fix of that second: stamped at the same edge
        if utc_s in edges:  # (the receiver keeps its newest 20 edges)
            off = m["stamp_ns"] - edges[utc_s]
            assert abs(off) <= window + 3 * RES_NS, (utc_s, off, window)
            checked += 1
    assert checked >= 3, (sorted(edges), [m["time_ref"] for m in refs])
    # one edge a second, one UTC second apart
    utcs = [m["time_ref"] // 10**9 for m in refs]
    assert utcs == list(range(utcs[0], utcs[0] + len(utcs)))
