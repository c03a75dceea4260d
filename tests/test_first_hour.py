"""A new user's first hour: what the CLI and the daemon do when things are not as they should be.
Every message that misses a recording has a number; ``run`` says when a board never came up.

The CLI runs as real processes; the full disk is a real 1 MiB tmpfs (skipped with the reason
where this user may not mount one; ``ML_REQUIRE_TMPFS=1``, as CI sets, makes that a failure)."""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

from .helpers import ML, board_process, ml, wait_for


@contextmanager
def tmpfs(where: Path, size: str) -> Iterator[Path]:
    where.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(where)],
                       capture_output=True, text=True)  # fmt: skip
    if r.returncode != 0:
        why = f"cannot mount a tmpfs here: {r.stderr.strip() or r.returncode}"
        if os.environ.get("ML_REQUIRE_TMPFS") == "1":
            raise RuntimeError(f"ML_REQUIRE_TMPFS=1 but {why}")
        pytest.skip(why)
    try:
        yield where
    finally:
        subprocess.run(["umount", "-l", str(where)], check=False)


# ---- 1. a full disk: recorded + dropped, and recover restores exactly the recorded ------------
@pytest.mark.slow
def test_a_full_disk_counts_every_message_it_could_not_keep(tmp_path: Path) -> None:
    with (
        tmpfs(tmp_path / "disk", "1m") as disk,
        board_process("--sim", "rate", "--rate", "4000", "--channels", "8", "--name", "r") as url,
    ):
        r = ml("run", url, "--record", str(disk / "rec"), "-p", "bus")
        assert r.returncode == 1, r.stderr
        assert "Traceback" not in r.stderr
        assert re.search(r"error: mcap: recording failed: No space left on device", r.stderr)
        pattern = r"publisher mcap: (\d+) messages, (\d+) dropped, recorded (\S+)"
        got = re.search(pattern, r.stderr)
        assert got, r.stderr
        recorded, dropped, bag = int(got[1]), int(got[2]), Path(got[3])
        assert dropped > 0 and recorded > 0
        out = tmp_path / "recovered"
        rec = ml("recover", str(bag), "--out", str(out))
    assert rec.returncode == 0, rec.stderr
    assert rec.stdout.strip() == f"recovered {recorded} messages into {out}"


# ---- 2. run's exit codes, one test each (docs/cli.md) -------------------------------------------
def free_tcp_url() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp://127.0.0.1:{s.getsockname()[1]}"


@pytest.mark.slow
def test_run_exits_0_when_its_boards_ran() -> None:
    with board_process("--sim", "rangers") as url:
        r = ml("run", url, "--duration", "2", "-p", "bus")
    assert r.returncode == 0, r.stderr
    assert "never up" not in r.stderr


@pytest.mark.slow
def test_run_exits_1_when_nothing_listens_at_a_board_it_was_given() -> None:
    url = free_tcp_url()
    with board_process("--sim", "rangers") as good:
        r = ml("run", good, url, "--duration", "2", "-p", "bus")
    assert r.returncode == 1, r.stderr
    (line,) = [ln for ln in r.stderr.splitlines() if "error:" in ln]
    assert line.startswith(f"missing-link: error: {url}: never up: ")
    assert "Connection refused" in line and "Traceback" not in r.stderr


@pytest.mark.slow
def test_run_exits_1_when_another_daemon_holds_the_port(tmp_path: Path) -> None:
    env = {**os.environ, "MISSING_LINK_CONTROL": f"{tmp_path}/c.sock"}
    board = subprocess.Popen(
        [*ML, "board", "--sim", "rangers", "--listen", "pty"], stdout=subprocess.PIPE, text=True
    )
    try:
        assert board.stdout is not None
        url = board.stdout.readline().split()[1]
        first = subprocess.Popen(
            [*ML, "run", url, "--duration", "60", "-p", "bus", "--wait-up", "30"],
            stderr=subprocess.PIPE,
            text=True,
            env=env,
        )
        try:
            # the first daemon has the port (serial ports are locked exclusively): its board is
            # up, asked through its control endpoint
            wait_for(lambda: ml("info", "board_b", timeout=30, env=env).returncode == 0, 60)
            r = ml("run", url, "--duration", "2", "-p", "bus")
        finally:
            first.terminate()
            first.wait(10)
    finally:
        board.terminate()
        board.wait(10)
    assert r.returncode == 1, r.stderr
    (line,) = [ln for ln in r.stderr.splitlines() if "error:" in ln]
    assert line.startswith(f"missing-link: error: {url}: never up: ")
    path = url.removeprefix("serial://")  # (the one who holds it, named: issue 45.9)
    assert f"{path} is held by another missing-link run (pid {first.pid}: missing-link run" in line


@pytest.mark.slow
def test_run_exits_2_on_bad_input_and_130_on_ctrl_c(tmp_path: Path) -> None:
    r = ml("run", "bogus://x", "--duration", "1")
    assert r.returncode == 2 and "unknown transport 'bogus'" in r.stderr
    with board_process("--sim", "rangers") as url:
        env = {**os.environ, "MISSING_LINK_CONTROL": f"{tmp_path}/c.sock"}
        p = subprocess.Popen(
            [*ML, "run", url, "-p", "bus"], stderr=subprocess.PIPE, text=True, env=env
        )
        wait_for(lambda: ml("info", "board_b", timeout=30, env=env).returncode == 0, 60)  # up
        p.send_signal(signal.SIGINT)
        _, err = p.communicate(timeout=20)
    assert p.returncode == 130, err
    assert "Traceback" not in err


# ---- 3. create-msgs for a daemon with several boards --------------------------------------------
@pytest.mark.slow
def test_create_msgs_writes_every_boards_types_named_as_the_daemon_names_them(
    tmp_path: Path,
) -> None:
    """Two boards whose ``temp`` differ, and a thesis board: one package with all of them, the
    names the daemon publishes under (board a first, as the daemon meets them here)."""
    from missing_link.daemon import Daemon
    from missing_link.daemon.config import BoardSpec, Config
    from missing_link.ros.package import read_manifest

    out = tmp_path / "ws"
    with (
        board_process("--sim", "hostile_dtype", "--name", "board_a") as a,
        board_process("--sim", "hostile_dtype", "--name", "board_b") as b,
        board_process("--sim", "rangers", "--name", "rangers") as c,
    ):
        cfg = tmp_path / "ml.toml"  # the daemon's config: board_a and rangers
        cfg.write_text(f'[[board]]\nurl = "{a}"\n[[board]]\nurl = "{c}"\n')
        r = ml("create-msgs", "--config", str(cfg), "--out", str(out))
        assert r.returncode == 0, r.stderr
        first = read_manifest(str(out / "missing_link_msgs"))
        assert first is not None
        assert {"Temp", "DistIr", "DistUs"} <= set(first[1])
        assert first[1]["Temp"].boards == ("board_a",) and first[1]["DistIr"].boards == ("rangers",)
        # Later, for board_b alone: board_a's and rangers' types stay, said in one line
        r = ml("create-msgs", b, "--out", str(out))
        assert r.returncode == 0, r.stderr
        assert "1 message type(s) from board_b" in r.stderr  # its Temp, the same as board_a's
        assert "kept 3 type(s) of rangers from the earlier run" in r.stderr
        second = read_manifest(str(out / "missing_link_msgs"))
        assert second is not None and set(first[1]) <= set(second[1])
        assert second[1]["Temp"].boards == ("board_a", "board_b")
        # and the daemon, meeting board_a then board_b, publishes under the same type names
        with Daemon(Config(boards=[BoardSpec(a)])) as d:
            assert d.wait_until_up(10)
            d.add_board(BoardSpec(b))
            assert wait_for(lambda: len(d.bus.topics) >= 2)
            daemon_types = {t.type_name.rsplit("/", 1)[1] for t in d.bus.topics.values()}
    assert daemon_types <= set(second[1])


@pytest.mark.slow
def test_create_msgs_qualifies_a_differing_type_like_the_daemon(tmp_path: Path, serve: Any) -> None:
    from missing_link.daemon import Daemon
    from missing_link.daemon.config import BoardSpec, Config
    from missing_link.ros.package import read_manifest
    from missing_link.virtual import make_sim

    out = tmp_path / "ws"
    a = serve(make_sim("hostile_dtype", name="board_a"), "tcp://127.0.0.1:0").url
    b = serve(make_sim("hostile_dtype", name="board_b", dtype="float"), "tcp://127.0.0.1:0").url
    r = ml("create-msgs", a, b, "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert "type missing_link_msgs/msg/Temp is already defined differently" in r.stderr
    manifest = read_manifest(str(out / "missing_link_msgs"))
    assert manifest is not None
    assert manifest[1]["Temp"].definition.endswith("int16[] values\n")
    assert manifest[1]["BoardBTemp"].definition.endswith("float32[] values\n")
    with Daemon(Config(boards=[BoardSpec(a)])) as d:
        assert d.wait_until_up(10)
        d.add_board(BoardSpec(b))
        assert wait_for(lambda: "/board_b/temp" in d.bus.topics)
        names = {n: t.type_name for n, t in d.bus.topics.items()}
    assert names["/board_a/temp"] == "missing_link_msgs/msg/Temp"
    assert names["/board_b/temp"] == "missing_link_msgs/msg/BoardBTemp"


# ---- 5. late joiners in-process; 6. subscribe() to a topic that does not exist ---------------
def test_a_late_bus_subscriber_asks_for_the_latest_state(serve: Any) -> None:
    from missing_link.daemon import Daemon
    from missing_link.daemon.config import BoardSpec, Config
    from missing_link.topics import Update
    from missing_link.virtual import make_sim

    server = serve(make_sim("thesis", seed=2))
    with Daemon(Config(boards=[BoardSpec(server.url)])) as d:
        assert d.wait_until_up(10)
        d.send("/thesis/servo/cmd", 21)
        assert wait_for(lambda: (u := d.bus.last("/thesis/servo")) is not None and u.values == [21])
        late: list[Update] = []
        d.subscribe("/thesis/servo", late.append, queue=0, latest=True)
        assert [u.values for u in late] == [[21]]  # at once, before any new state
        with pytest.raises(KeyError, match=r"no topic '/thesis/sevro'.*/thesis/servo"):
            d.subscribe("/thesis/sevro", late.append)
        d.subscribe("/thesis/*", late.append)  # patterns may match later topics


def test_subscribing_before_the_board_is_up_is_fine(serve: Any) -> None:
    from missing_link.daemon import Daemon
    from missing_link.daemon.config import BoardSpec, Config

    url = free_tcp_url()  # nothing there yet
    with Daemon(Config(boards=[BoardSpec(url)])) as d:
        d.subscribe("/thesis/quad", lambda u: None)  # the board may come up later


@pytest.mark.slow
def test_call_value_is_what_send_sends_and_board_text_is_text(serve: Any) -> None:
    """``call --value 40`` packs 40 as the servo's int8 (``--hex 40`` is 0x40 = 64); a
    board's error text is shown as text, in the one error line too."""
    from missing_link.virtual import make_sim

    url = serve(make_sim("thesis", seed=3), "tcp://127.0.0.1:0").url
    r = ml("call", url, "a2j_set_servo", "--value", "40", "--json")
    assert r.returncode == 0, r.stderr
    r = ml("call", url, "a2j_set_servo", "--value", "300")
    assert r.returncode == 2 and "'300': servo: 300 is beyond int8_t (-128..127)" in r.stderr
    r = ml("call", url, "a2jEcho", "--value", "1")
    assert r.returncode == 2 and "no actuator of thesis is called through a2jEcho" in r.stderr
    r = ml("call", url, "setTriggerAt", "--hex", "0000000000000000")  # before any host map
    assert r.returncode == 1
    assert "  text  no host map yet (a2jHostMap)" in r.stdout
    (line,) = [ln for ln in r.stderr.splitlines() if "error:" in ln]
    assert "setTriggerAt returned 0xff: no host map yet (a2jHostMap)" in line


def test_console_shows_scaled_values_in_their_unit() -> None:
    import io

    from missing_link.descriptors import parse_transds
    from missing_link.publishers.console import ConsolePublisher
    from missing_link.topics import Topic, Update

    (servo,) = parse_transds(
        "transds/1\nservo,3,hs645,HS-645MG,1,int8_t,-128,unit=deg,scale=0.708661\n"
    )
    out = io.StringIO()
    topic = Topic.for_transducer("/b/servo", "b", servo, "missing_link_msgs")
    ConsolePublisher({}, out=out).publish(
        Update.build(topic=topic, board_us=[1], host_ns=[5], values=[20], seq=0, lost=0, recv_ns=0)
    )
    assert out.getvalue().rstrip().endswith("/b/servo [14.17] deg (raw [20])")


@pytest.mark.slow
def test_a_failed_connect_names_its_board_once_and_prints_nothing_else() -> None:
    probe = (
        "import missing_link\n"
        "try:\n"
        f"    missing_link.connect({free_tcp_url()!r}, wait=1.5)\n"
        "except missing_link.BoardError as e:\n"
        "    print(e)\n"
    )
    r = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60)
    assert r.stderr == ""  # a library prints no retry lines of its own
    (line,) = r.stdout.splitlines()
    url = line.split(": ", 1)[0]
    assert line.count(url) == 1 and "not up within 1.5 s: cannot connect" in line


@pytest.mark.slow
def test_zenoh_says_where_it_is_and_that_nothing_answers() -> None:
    with board_process("--sim", "rangers") as url:
        port = free_tcp_url().rsplit(":", 1)[1]
        cfg = f'[zenoh]\nconnect = ["tcp/127.0.0.1:{port}"]\n'
        import tempfile

        with tempfile.NamedTemporaryFile("w", suffix=".toml", delete=False) as f:
            f.write(cfg)
        r = ml("run", url, "-p", "zenoh", "--config", f.name, "--duration", "1")
        os.unlink(f.name)
    assert r.returncode == 0, r.stderr
    assert (
        "missing-link: zenoh at peer " in r.stderr and f"connect tcp/127.0.0.1:{port}" in r.stderr
    )
    assert f"zenoh: nothing answers at tcp/127.0.0.1:{port} yet" in r.stderr
