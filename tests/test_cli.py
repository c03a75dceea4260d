"""The missing-link command line, run as real processes against a virtual board process."""

from __future__ import annotations

import ast
import json
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from missing_link.virtual.process import start_board_process, stop_process

from .helpers import ml

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def board_url() -> Iterator[str]:
    proc, url = start_board_process("thesis", seed=5, listen="pty")
    try:
        yield url
    finally:
        stop_process(proc)


def test_board_prints_one_listening_line_and_stops_on_sigterm() -> None:
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "missing_link",
            "board",
            "--sim",
            "rangers",
            "--listen",
            "tcp://127.0.0.1:0",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None
    line = proc.stdout.readline()
    assert line.startswith("LISTENING tcp://127.0.0.1:") and line.endswith("\n")
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(10) == 0
    assert proc.stdout.read() == ""  # exactly one line


def test_info_json(board_url: str) -> None:
    r = ml("info", board_url, "--json")
    assert r.returncode == 0, r.stderr
    info = json.loads(r.stdout)
    assert info["url"] == board_url and info["original"] is False
    assert info["functions"][1] == {"index": 1, "name": "a2jMany"}
    assert info["properties"]["board.name"] == "thesis"
    quad = info["transducers"][0]
    assert quad["name"] == "quad" and quad["type"] == "int16_t" and quad["na"] == -1


def test_info_text(board_url: str) -> None:
    r = ml("info", board_url)
    assert r.returncode == 0
    assert "functions:" in r.stdout and "GP2Y0A02YK" in r.stdout


def test_call_json_and_text(board_url: str) -> None:
    r = ml("call", board_url, "a2jEcho", "--hex", "12 ed 7d", "--json")
    assert json.loads(r.stdout) == {
        "function": "a2jEcho",
        "code": 186,
        "ok": False,
        "payload": "12ed7d",
    }
    r = ml("call", board_url, "getTime")
    assert r.returncode == 0 and r.stdout.startswith("return 0x00 (0)  payload 8 bytes")


def test_listen_count_json(board_url: str) -> None:
    r = ml("listen", board_url, "--count", "25", "--json", "-t", "dist_ir")
    assert r.returncode == 0, r.stderr
    lines = [json.loads(x) for x in r.stdout.splitlines()]
    assert len(lines) == 25
    assert {x["transducer"] for x in lines} == {"dist_ir"}
    assert all(200 <= x["value"] <= 1500 and x["board_us"] > 0 for x in lines)


def test_errors_go_to_stderr_with_exit_codes(board_url: str) -> None:
    r = ml("call", board_url, "noSuchFunction")
    assert r.returncode == 1 and r.stdout == ""
    assert "no function 'noSuchFunction'" in r.stderr
    r = ml("info", "tcp://127.0.0.1:1")
    assert r.returncode == 1 and "cannot connect" in r.stderr
    r = ml("info", "bogus")
    assert r.returncode == 2 and "not a board URL" in r.stderr
    r = ml("call", board_url, "a2jEcho", "--hex", "zz")
    assert r.returncode == 2 and "--hex 'zz' is not hex" in r.stderr
    r = ml("board", "--sim", "nosuch", "--listen", "pty")
    assert r.returncode == 2 and "unknown sim 'nosuch'" in r.stderr


def test_demo_runs_and_exits_zero(tmp_path: object) -> None:
    r = ml("demo", "--duration", "3", "--record", str(tmp_path), timeout=60)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "demo finished OK" in r.stdout
    sent = int(r.stdout.split("servo commands sent:")[1].split()[0])
    assert sent > 10  # the encoder steered the servo through the actuator topic
    assert f"recording: {tmp_path}/demo_" in r.stdout
    # the summary says what its columns count, and why a Range topic runs at channels x rate
    legend = " ".join(r.stdout.split("summary", 1)[1].split())
    assert "samples: channel values that arrived" in legend and "N/A: channels the board" in legend
    assert "so it runs at channels x the transducer's rate" in legend


def test_create_msgs_from_board_and_file(board_url: str, tmp_path: object) -> None:
    out = str(tmp_path)
    r = ml("create-msgs", board_url, "--out", out, "--package", "thesis_msgs")
    assert r.returncode == 0, r.stderr
    written = r.stdout.split()
    assert f"{out}/thesis_msgs/msg/DistUs.msg" in written
    with open(f"{out}/thesis_msgs/msg/DistUs.msg") as f:
        assert f.read().endswith("builtin_interfaces/Time[] times\nuint32[] values\n")
    r = ml("create-msgs", "examples/original-board.toml", "--out", out, "--ros", "1")
    assert r.returncode == 0
    with open(f"{out}/missing_link_msgs/msg/Quad.msg") as f:
        assert "time[] times\nint16[] values" in f.read()
    r = ml("create-msgs", board_url, "--out", out, "--package", "Bad-Name")
    assert r.returncode == 2 and "package name 'Bad-Name'" in r.stderr


def test_run_and_recover_input_errors(tmp_path: Path) -> None:
    r = ml("run", "tcp://127.0.0.1:1", "-p", "zenohh", "--duration", "0.1")
    assert r.returncode == 2 and "--publisher 'zenohh': unknown" in r.stderr
    r = ml("run")
    assert r.returncode == 2 and "no boards" in r.stderr
    r = ml("recover", str(tmp_path))
    assert r.returncode == 2 and "no .mcap file" in r.stderr
    mcap = Path(str(tmp_path)) / "x.mcap"
    mcap.write_bytes(b"\x89MCAP0\r\n")
    r = ml("recover", str(mcap), "--out", str(tmp_path))
    assert r.returncode == 2 and "exists already" in r.stderr
    r = ml("recover", "examples/original-board.toml", "--out", str(tmp_path / "new"))
    assert r.returncode == 2 and "not an MCAP file" in r.stderr


def test_run_help_lists_exactly_the_publishers_available_here() -> None:
    """Without importing the heavy ones to find out (rclpy, zenoh, foxglove)."""
    probe = (
        "import sys, contextlib, io\n"
        "from missing_link.cli.main import build_parser\n"
        "from missing_link.publishers.registry import available_publishers\n"
        "buf = io.StringIO()\n"
        "with contextlib.redirect_stdout(buf), contextlib.suppress(SystemExit):\n"
        "    build_parser().parse_args(['run', '--help'])\n"
        "print(repr(buf.getvalue()))\n"
        "print(','.join(available_publishers()))\n"
        "print(','.join(m for m in ('zenoh', 'rclpy', 'foxglove', 'rospy') if m in sys.modules))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, timeout=60, check=True
    ).stdout.splitlines()
    help_text, available, heavy = " ".join(ast.literal_eval(out[0]).split()), out[1], out[2]
    assert f"add a publisher ({available.replace(',', ', ')} here)" in help_text
    assert heavy == ""  # nothing heavy was imported to list them
    import importlib.util

    assert ("ros2" in available.split(",")) == (importlib.util.find_spec("rclpy") is not None)


def test_a_publisher_this_environment_lacks_is_one_line_naming_what_it_needs() -> None:
    import importlib.util

    if importlib.util.find_spec("rclpy") is not None:
        pytest.skip("rclpy is installed here: ros2 is available")
    r = ml("run", "tcp://127.0.0.1:1", "-p", "ros2", "--duration", "1")
    assert r.returncode == 2
    (line,) = r.stderr.strip().splitlines()
    assert "--publisher 'ros2': needs rclpy" in line
    r = ml("run", "tcp://127.0.0.1:1", "-p", "zenohh")
    assert r.returncode == 2 and "unknown (available here: " in r.stderr


def test_docs_cli_names_every_command_and_option() -> None:
    """docs/cli.md says what the CLI does: every command and every long option is in it."""
    from missing_link.cli.main import build_parser

    doc = (Path(__file__).resolve().parents[1] / "docs" / "cli.md").read_text()
    parser = build_parser()
    commands = next(a for a in parser._actions if a.dest == "command").choices  # type: ignore[attr-defined]
    missing = [
        f"{name} {opt}"
        for name, sp in commands.items()
        for a in sp._actions
        for opt in a.option_strings
        if opt.startswith("--") and opt != "--help" and opt not in doc
    ]
    missing += [name for name in commands if f"missing-link {name}" not in doc]
    assert not missing, f"docs/cli.md does not mention: {missing}"
