"""Real ROS 2: `run -p ros2` (rclpy + rmw_fastrtps_cpp from the Kilted wheels) heard by an
independent rclpy node that imports nothing from missing_link (tests/ros2_rclpy_listener.py).

The ROS 2 environment is `.venv-ros2` (made by `make ros2`, which `make test` runs; its path comes
in as ML_ROS2_PYTHON).  Without it these tests are skipped with the reason, unless
ML_REQUIRE_ROS2=1 (set by `.ci/run`) makes that a failure.  DDS runs on 127.0.0.1 only
(tests/fastdds_loopback.xml: unicast discovery, no multicast), each test in a domain of its own.
"""

from __future__ import annotations

import json
import os
import random
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from .helpers import board_process, ml

pytestmark = [pytest.mark.slow]  # (every test here starts a process: make check skips them)

ROOT = Path(__file__).resolve().parents[1]
ROS2_PY = Path(os.environ.get("ML_ROS2_PYTHON") or ROOT / ".venv-ros2" / "bin" / "python")
LISTENER = Path(__file__).with_name("ros2_rclpy_listener.py")
PROFILE = Path(__file__).with_name("fastdds_loopback.xml")

if not ROS2_PY.exists():
    if os.environ.get("ML_REQUIRE_ROS2") == "1":
        raise RuntimeError(f"ML_REQUIRE_ROS2=1 but {ROS2_PY} is missing: make ros2")
    pytestmark += [pytest.mark.skip(reason=f"ROS 2 wheels not installed ({ROS2_PY}; make ros2)")]


def ros_env(**extra: str) -> dict[str, str]:
    env = {
        k: v
        for k, v in os.environ.items()
        if not k.startswith(("ROS_", "FASTDDS", "_ROS_WHEELS", "AMENT", "LD_LIBRARY"))
    }
    env.update(
        ROS_DOMAIN_ID=str(random.randrange(1, 200)),
        FASTDDS_DEFAULT_PROFILES_FILE=str(PROFILE),
        ROS_DISTRO="kilted",
        # the host only, as the loopback profile: the daemon then takes commands from this face
        ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
        PYTHONUNBUFFERED="1",
    )
    env.update(extra)
    return env


@pytest.fixture
def thesis_board() -> Iterator[str]:
    with board_process("--sim", "thesis") as url:
        yield url


def start_daemon(url: str, env: dict[str, str], *extra: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [str(ROS2_PY), "-m", "missing_link", "run", url, "-p", "ros2", "--duration", "60", *extra],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )


def listen(env: dict[str, str], *args: str, timeout: float = 90) -> dict[str, object]:
    r = subprocess.run(
        [str(ROS2_PY), str(LISTENER), *args],
        capture_output=True,
        text=True,
        env=env,
        timeout=timeout,
    )
    assert r.returncode == 0, r.stderr[-3000:]
    result: dict[str, object] = json.loads(r.stdout.strip().splitlines()[-1])
    return result


def build_types(source: str, tmp_path: Path, env: dict[str, str]) -> Path:
    """``create-msgs SOURCE --build PREFIX`` with the ROS 2 of .venv-ros2; returns PREFIX."""
    prefix = tmp_path / "install"
    r = subprocess.run(
        [
            *(str(ROS2_PY), "-m", "missing_link", "create-msgs", source),
            *("--out", str(tmp_path / "src"), "--build", str(prefix)),
        ],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr[-3000:]
    return prefix


def stop(p: subprocess.Popen[str]) -> str:
    p.terminate()
    _out, err = p.communicate(timeout=30)
    return err


def test_stock_rclpy_hears_standard_types_diagnostics_and_the_graph(thesis_board: str) -> None:
    env = ros_env()
    daemon = start_daemon(thesis_board, env)
    try:
        got = listen(
            env,
            "--seconds",
            "40",
            "--sub",
            "/thesis/dist_ir/range=sensor_msgs/msg/Range",
            "--sub",
            "/diagnostics=diagnostic_msgs/msg/DiagnosticArray",
        )
        sensor = listen(
            env,
            "--seconds",
            "30",
            "--sensor-qos",
            "--sub",
            "/thesis/dist_us/range=sensor_msgs/msg/Range",
        )
    finally:
        err = stop(daemon)
    counts = got["counts"]
    assert isinstance(counts, dict)
    assert all(n >= 3 for n in counts.values()), (counts, err[-2000:])
    received = got["received"]
    assert isinstance(received, dict)
    now = time.time_ns()
    for r in received["/thesis/dist_ir/range"]:
        assert r["frame_id"].startswith("thesis/dist_ir/")
        assert 0.1 <= r["range"] <= 2.0 and r["radiation_type"] == 1  # INFRARED, metres
        assert abs(r["stamp_ns"] - now) < 60 * 10**9  # synchronised host time, not board time
    (diag,) = received["/diagnostics"][-1:]
    names = [s["name"] for s in diag["status"]]
    assert "missing_link: thesis" in names and "missing_link publisher: ros2" in names
    topics = got["topics"]
    assert isinstance(topics, dict)
    assert topics["/thesis/dist_ir/range"] == ["sensor_msgs/msg/Range"]
    assert topics["/diagnostics"] == ["diagnostic_msgs/msg/DiagnosticArray"]
    assert "missing_link" in got["nodes"]  # type: ignore[operator]
    assert sensor["counts"]["/thesis/dist_us/range"] >= 3  # type: ignore[index]
    # thesis types were not built: one line for them all says how (issue 45.8: a line per
    # type before), and the face is not in a warning state for it on /diagnostics
    said = [ln for ln in err.splitlines() if "create-msgs" in ln]
    assert len(said) == 1 and "create-msgs <board URL> --ros 2 --build PREFIX" in said[0], err
    (ros2,) = [s for s in diag["status"] if s["name"] == "missing_link publisher: ros2"]
    assert ros2["level"] == 0 and "thesis-format type(s) not built" in ros2["message"], ros2


def test_thesis_types_after_create_msgs_build_and_ros2_commands(
    thesis_board: str, tmp_path: Path
) -> None:
    env = ros_env()
    prefix = build_types(thesis_board, tmp_path, env)
    daemon = start_daemon(thesis_board, {**env, "MISSING_LINK_ROS2_PREFIX": str(prefix)})
    site = prefix / "lib" / f"python{sys.version_info[0]}.{sys.version_info[1]}" / "site-packages"
    listener_env = {**env, "PYTHONPATH": str(site), "LD_LIBRARY_PATH": str(prefix / "lib")}
    try:
        got = listen(
            listener_env,
            "--seconds",
            "60",
            "--sub",
            "/thesis/dist_ir=missing_link_msgs/msg/DistIr",
            "--sub",
            "/thesis/servo=missing_link_msgs/msg/Servo",
            "--sub",
            "/thesis/servo/joint_states=sensor_msgs/msg/JointState",
            "--min",
            "1",
            "--cmd",
            "/thesis/servo/cmd=missing_link_msgs/msg/Servo=40",
            "--until-value",
            "/thesis/servo=40",
        )
        # a timed command: times[0] 300 ms ahead; the board acts then and says so
        timed = listen(
            listener_env,
            *("--seconds", "30", "--min", "0"),
            *("--sub", "/thesis/servo=missing_link_msgs/msg/Servo"),
            *("--cmd", "/thesis/servo/cmd=missing_link_msgs/msg/Servo=-30@300"),
            *("--until-value", "/thesis/servo=-30"),
        )
        time.sleep(1.0)  # the servo has settled: its state goes out no more
        late = listen(
            listener_env,
            *("--seconds", "20", "--min", "1", "--transient-local"),
            *("--sub", "/thesis/servo=missing_link_msgs/msg/Servo"),
        )
    finally:
        err = stop(daemon)
    # each timed command acted at its asked time: the servo's state is reported then (where
    # it is when the command takes effect; it moves towards -30 over the next frames)
    stamps = [m["times_ns"][0] for m in timed["received"]["/thesis/servo"]]  # type: ignore[index]
    sent = timed["sent_at_ns"]
    assert isinstance(sent, list) and sent, timed
    acted = [at for at in sent if any(abs(s - at) <= 200_000 for s in stamps)]
    assert len(acted) >= max(1, len(sent) - 1), (sent, stamps)
    # a late transient-local subscriber gets the servo's current state all the same
    late_values = [v for m in late["received"]["/thesis/servo"] for v in m["values"]]  # type: ignore[index]
    assert late_values == [-30], (late_values, err[-2000:])
    received = got["received"]
    assert isinstance(received, dict), err[-2000:]
    dist = received["/thesis/dist_ir"]
    assert dist and all(len(m["values"]) == 8 and len(m["times_ns"]) == 8 for m in dist)
    servo_values = [v for m in received["/thesis/servo"] for v in m["values"]]
    assert 40 in servo_values, (servo_values, err[-2000:])  # the rclpy command moved the servo
    # ... and the standard JointState says so in radians: 40 x 0.708661 deg
    positions = [p for m in received["/thesis/servo/joint_states"] for p in m["position"]]
    assert any(abs(p - 0.4948) < 0.01 for p in positions), positions
    topics = got["topics"]
    assert isinstance(topics, dict)
    assert topics["/thesis/dist_ir"] == ["missing_link_msgs/msg/DistIr"]
    assert "not published" not in err


def test_a_built_type_that_differs_from_the_board_is_refused(
    thesis_board: str, tmp_path: Path
) -> None:
    """The package was built when dist_ir was int32; the board now says uint16: the daemon
    refuses to publish DistIr (never sent wrong), says why, and the rest still goes out."""
    desc = tmp_path / "old.txt"
    desc.write_text("transds/1\ndist_ir,1,sharp,GP2Y0A02YK,8,int32_t,0\n")
    env = ros_env()
    prefix = build_types(str(desc), tmp_path, env)
    daemon = start_daemon(thesis_board, {**env, "MISSING_LINK_ROS2_PREFIX": str(prefix)})
    try:
        got = listen(env, "--seconds", "30", "--sub", "/thesis/dist_ir/range=sensor_msgs/msg/Range")
    finally:
        err = stop(daemon)
    assert got["counts"]["/thesis/dist_ir/range"] >= 3  # type: ignore[index]
    assert "missing_link_msgs/msg/DistIr is not published: the built type has" in err
    assert "sequence<int32>" in err and "sequence<uint16>" in err
    topics = got["topics"]
    assert isinstance(topics, dict) and "/thesis/dist_ir" not in topics


def test_run_help_names_ros2_where_rclpy_is() -> None:
    """In the ROS 2 environment the help names every publisher available there, ros2 too."""
    out = subprocess.run(
        [str(ROS2_PY), "-m", "missing_link", "run", "--help"],
        capture_output=True,
        text=True,
        timeout=60,
        env=ros_env(),
    ).stdout
    listed = " ".join(out.split()).split("add a publisher (")[1].split(" here)")[0].split(", ")
    assert "ros2" in listed and "zenoh" in listed


PARAMS = Path(__file__).with_name("ros2_param_client.py")


def parameters_set(
    board_url: str, tmp_path: Path, args: list[str], *daemon_args: str
) -> tuple[dict[str, Any], subprocess.CompletedProcess[str], str]:
    """A daemon (``daemon_args``) on the board with its control endpoint, and a stock rclpy
    parameter client in its own process (ros2_param_client.py ``args``, parameters under
    ``thesis.``): what the client got, the board's configuration read back through the
    daemon (``missing-link config thesis --json``), and what the daemon said."""
    env = ros_env(MISSING_LINK_CONTROL=str(tmp_path / "control.sock"))
    daemon = start_daemon(board_url, env, *daemon_args)
    try:
        r = subprocess.run(
            [str(ROS2_PY), str(PARAMS), "--prefix", "thesis.", *args],
            capture_output=True,
            text=True,
            env=env,
            timeout=120,
        )
        assert r.returncode == 0, r.stderr[-3000:]
        got = json.loads(r.stdout.strip().splitlines()[-1])
        board = ml("config", "thesis", "--json", env=env, timeout=60)
    finally:
        err = stop(daemon)
    return got, board, err


def test_board_configuration_is_ros2_parameters_of_the_node(
    thesis_board: str, tmp_path: Path
) -> None:
    """Every key of the board's run-time configuration is a parameter of /missing_link, named
    <board>.<transducer>.<key>, with its range (read-only where the board says so); a stock
    rclpy parameter client in its own process sets one, and the board changes (read back
    through the daemon's control endpoint); a set the board refuses is an unsuccessful result
    with the board's reason, and nothing changes."""
    got, board, err = parameters_set(
        thesis_board,
        tmp_path,
        [
            *("--describe", "thesis.dist_ir.rate_hz", "--describe", "thesis.dist_us.groups"),
            *("--set", "thesis.dist_ir.rate_hz=double:5.0"),
            *("--set", "thesis.servo.min_deg=integer:60"),
            *("--set", "thesis.servo.max_deg=integer:50"),  # below min_deg: refused
            *("--set", "thesis.dist_ir.rate_hz=double:99.0"),  # outside the range
        ],
    )
    assert "thesis.servo.enabled" in got["names"], err[-3000:]
    d = got["descriptors"]
    assert d["thesis.dist_ir.rate_hz"]["float_range"] == [[0.1, 26.0]]
    assert d["thesis.dist_us.groups"]["read_only"] is True
    ok, refused_combo, ok2, out_of_range = got["results"]
    assert ok["successful"], ok
    assert refused_combo["successful"], refused_combo  # 60 < max_deg 90: fine on its own
    assert not ok2["successful"] and "min_deg < max_deg" in ok2["reason"], ok2  # 60 vs 50
    assert not out_of_range["successful"], out_of_range
    assert got["values"]["thesis.dist_ir.rate_hz"] == 5.0
    assert got["values"]["thesis.servo.max_deg"] == 90  # the refused set changed nothing
    assert board.returncode == 0, board.stderr + err[-2000:]
    values = json.loads(board.stdout)["values"]
    assert values["dist_ir.rate_hz"] == 5.0 and values["servo.min_deg"] == 60
    assert values["servo.max_deg"] == 90


def test_an_actuators_parameters_are_commands(thesis_board: str, tmp_path: Path) -> None:
    """With ``[ros2] commands = false`` a stock rclpy client may set a sensor's key but not the
    servo's (its keys are commands: docs/security.md): an unsuccessful result saying so, and
    the board keeps its value."""
    cfg = tmp_path / "off.toml"
    cfg.write_text("[ros2]\ncommands = false\n")
    sets = [*("--set", "thesis.dist_ir.rate_hz=double:5.0")]
    sets += [*("--set", "thesis.servo.failsafe_ms=integer:0")]
    got, board, err = parameters_set(thesis_board, tmp_path, sets, "--config", str(cfg))
    sensor, servo = got["results"]
    assert sensor["successful"], (sensor, err[-2000:])
    assert not servo["successful"] and "commands are off on ros2" in servo["reason"], servo
    values = json.loads(board.stdout)["values"]
    assert values["dist_ir.rate_hz"] == 5.0 and values["servo.failsafe_ms"] != 0


def test_ros_security_variables_reach_rcl(thesis_board: str) -> None:
    """The rclpy node honours SROS2's ROS_SECURITY_* as any node does: with enforcement on and
    no keystore it does not start (one line, exit 1) rather than talk unsecured."""
    env = ros_env(
        ROS_SECURITY_ENABLE="true",
        ROS_SECURITY_STRATEGY="Enforce",
        ROS_SECURITY_KEYSTORE="/nonexistent/keystore",
    )
    r = subprocess.run(
        [str(ROS2_PY), "-m", "missing_link", "run", thesis_board, "-p", "ros2", "--duration", "5"],
        capture_output=True,
        text=True,
        timeout=60,
        env=env,
    )
    assert r.returncode == 1, r.stderr
    assert "SECURITY ERROR" in r.stderr and "/nonexistent/keystore" in r.stderr
    assert r.stderr.strip().count("\n") == 0, r.stderr  # one line, no traceback


def test_a_refused_command_says_once_what_turns_commands_on(
    thesis_board: str, tmp_path: Path
) -> None:
    """The README's `ros2 topic pub` on a daemon whose ros2 face takes no commands: one line
    naming the variable and the key that turn them on, then counted (before: a line per
    command, naming neither)."""
    cfg = tmp_path / "off.toml"
    cfg.write_text("[ros2]\ncommands = false\n")
    env = ros_env(MISSING_LINK_CONTROL=str(tmp_path / "control.sock"))
    daemon = start_daemon(thesis_board, env, "--config", str(cfg))
    try:
        got = listen(
            env, "--seconds", "30", "--min", "1", "--min-sent", "3",
            "--sub", "/thesis/dist_ir/range=sensor_msgs/msg/Range",
            "--cmd", "/thesis/servo/command=std_msgs/msg/Float64=0.5",
        )  # fmt: skip
    finally:
        err = stop(daemon)
    assert got["sent"] >= 3  # (matched: the daemon had them)
    lines = [ln for ln in err.splitlines() if "/thesis/servo/command refused" in ln]
    assert len(lines) == 1, err[-3000:]
    assert "ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST" in lines[0], lines[0]
    assert "[ros2] commands = true" in lines[0] and "counted" in lines[0], lines[0]
