"""A board's run-time configuration on every host face: the daemon's config file (applied at
every connect and after a board reset), ``Daemon.configure``/``Daemon.call``, the status and
``/diagnostics``, and the CLI reaching a board the daemon holds over its control endpoint (a
serial port the daemon has locked), by URL or board name."""

from __future__ import annotations

import json
import os
import re
import stat
import subprocess
from pathlib import Path

import pytest

from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config, ConfigError, parse_config
from missing_link.daemon.control.endpoint import ask
from missing_link.topics import Update
from missing_link.virtual.process import start_board_process, stop_process

from .helpers import ML, ml, wait_for


@pytest.mark.slow
def test_config_file_keys_are_applied_at_connect_and_after_a_board_reset(tmp_path: Path) -> None:
    """[boards.<name>.config] at every connect; a board that resets (its clock starts over, the
    link stays) forgot them, and gets them again; the topic's rate follows."""
    proc, url = start_board_process(
        "thesis", 3, "pty", extra=["--reset-at", "4", "--boot-gap-ms", "100"]
    )
    try:
        cfg = parse_config(
            {
                "board": [{"url": url}],
                "boards": {"thesis": {"config": {"dist_ir.rate_hz": 5, "servo.min_deg": -45}}},
            }
        )
        with Daemon(cfg) as d:
            got: list[Update] = []
            d.subscribe("/thesis/dist_ir", got.append, queue=0)
            assert d.wait_until_up(10)
            assert d.board_config("thesis")["dist_ir.rate_hz"] == 5.0
            st = d.status()[0]
            assert (
                "dist_ir.rate_hz=5" in st["config"]
                and "config file (connect)" in st["config_changed_by"]
            )
            assert wait_for(lambda: d.status()[0]["sync_resets"] >= 1, 10)  # the board reset
            assert wait_for(lambda: "board reset" in d.status()[0]["config_changed_by"], 5)
            assert d.board_config("thesis")["servo.min_deg"] == -45
            n = len(got)
            wait_for(lambda: len(got) >= n + 12, 15)  # (the first of them perhaps on its way)
            # 5 Hz after the reset too: the mean of ten periods (a virtual board stamps a sample
            # when its loop reads it, late by up to 0.4 s on a busy machine, measured; its grid
            # stays, and the rate is the configuration's)
            recent = [u.board_us[0] for u in got[-11:]]
            assert 150_000 <= (recent[-1] - recent[0]) / 10 <= 250_000, recent
    finally:
        stop_process(proc)


@pytest.mark.slow
def test_bad_keys_in_the_config_file_are_a_warning_and_the_board_runs() -> None:
    proc, url = start_board_process("thesis", 3, "pty")
    try:
        cfg = parse_config(
            {"board": [{"url": url}], "boards": {"thesis": {"config": {"dist_ir.rate_hz": 99}}}}
        )
        with Daemon(cfg) as d:
            assert d.wait_until_up(10)
            st = d.status()[0]
            assert "0.1..26" in st["warnings"] and st["state"] == "up"
            assert d.board_config("thesis")["dist_ir.rate_hz"] == 25.0
    finally:
        stop_process(proc)


@pytest.mark.parametrize(
    ("doc", "said"),
    [
        ({"boards": {"Thesis": {"config": {}}}}, "not a board name"),
        ({"boards": {"thesis": {"cfg": {}}}}, "has two tables, config and ros"),
        ({"boards": {"thesis": {"config": {"rate": 1}}}}, "<transducer>.<key>"),
        ({"boards": {"thesis": {"config": {"a.b": [1]}}}}, "expected a value"),
        ({"daemon": {"control": "relative.sock"}}, "absolute path"),
    ],
)
def test_config_file_errors_name_the_table_and_key(doc: dict[str, object], said: str) -> None:
    with pytest.raises(ConfigError, match=said):
        parse_config(doc, "robot.toml")


@pytest.mark.slow
def test_the_cli_reaches_a_board_the_daemon_holds(tmp_path: Path) -> None:
    """The daemon holds a pty board (its serial port locked); info, call and config by URL
    and by name go through the daemon's control endpoint (a 0600 socket in a 0700 directory),
    a set is seen by the daemon's own status, and errors keep their exit codes."""
    control = tmp_path / "run" / "control.sock"
    control.parent.mkdir(mode=0o700)  # (no directory is made for a control path but the default)
    env = {**os.environ, "MISSING_LINK_CONTROL": str(control)}
    proc, url = start_board_process("thesis", 5, "pty")
    nowhere = "tcp://127.0.0.1:1"  # a board the daemon holds that never comes up
    daemon = subprocess.Popen(
        [*ML, "run", url, nowhere, "-p", "bus", "--duration", "60"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        assert wait_for(lambda: control.exists(), 15)
        assert stat.S_IMODE(os.stat(control).st_mode) == 0o600
        assert stat.S_IMODE(os.stat(control.parent).st_mode) == 0o700
        # the socket is there before the boards are up: a board not up yet is one line, exit 1
        r = ml("info", nowhere, "--json", env=env)
        assert r.returncode == 1 and r.stderr.count("\n") == 1, r.stderr
        assert f"{nowhere}: not up (" in r.stderr and "Traceback" not in r.stderr, r.stderr
        assert wait_for(
            lambda: ask(str(control), {"op": "find", "board": url})["state"] == "up", 15
        )
        r = ml("info", url, "--json", env=env)
        assert r.returncode == 0, r.stderr
        assert json.loads(r.stdout)["name"] == "thesis"  # (not "Could not exclusively lock")
        r = ml("call", "thesis", "a2jEcho", "--hex", "0102", "--json", env=env)
        assert r.returncode == 0 and json.loads(r.stdout)["payload"] == "0102", r.stderr
        r = ml("config", url, "dist_ir.rate_hz=4", "servo.enabled=false", env=env)
        assert r.returncode == 0, r.stderr
        shown = dict(re.split(r"\s+= ", line, maxsplit=1) for line in r.stdout.splitlines())
        assert shown["dist_ir.rate_hz"] == "4" and shown["servo.enabled"] == "false", r.stdout
        r = ml("config", "thesis", "dist_ir.rate_hz=40", env=env)
        assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
        assert "0.1..26" in r.stderr
        r = ml("config", "thesis", "servo.min_deg=50", "servo.max_deg=10", env=env)
        assert r.returncode == 2 and "min_deg < max_deg" in r.stderr, r.stderr
        r = ml("config", "thesis", "--json", "-v", env=env)
        got = json.loads(r.stdout)
        assert got["values"]["dist_ir.rate_hz"] == 4.0 and got["values"]["servo.min_deg"] == -90
        assert got["state"] == "changed" and got["keys"][0]["allowed"] == "true or false"
        r = ml("call", "thesis", "a2j_set_servo", "--value", "10", env=env)
        assert r.returncode == 1 and "disabled" in r.stderr, r.stderr
        r = ml("config", "nosuchboard", env=env)
        assert r.returncode == 2 and "not a board URL" in r.stderr
    finally:
        daemon.terminate()
        _out, err = daemon.communicate(timeout=30)
        stop_process(proc)
    assert not control.exists(), err  # removed when the daemon stops


@pytest.mark.slow
def test_daemon_call_and_configure_from_python() -> None:
    proc, url = start_board_process("thesis", 6, "pty")
    try:
        with Daemon(Config(boards=[BoardSpec(url)], diagnostics_period=0.1)) as d:
            assert d.wait_until_up(10)
            assert d.call("thesis", "a2jEcho", b"hi").payload == b"hi"
            assert d.call(url, "a2jEcho", b"hi").code == 0xBA
            got = d.configure("thesis", {"dist_us.rate_hz": 2.5})
            assert got["dist_us.rate_hz"] == 2.5
            st = d.status()[0]
            assert st["config_changes"] == 1 and "dist_us.rate_hz=2.5" in st["config_changed_by"]
            assert st["configurable"] is True and st["config_state"] == "changed"
            with pytest.raises(ConfigError, match="no such key"):
                d.configure("thesis", {"dist_us.speed": 1})
            from missing_link.errors import BoardError

            with pytest.raises(BoardError, match="no such board"):
                d.configure("other", {})
    finally:
        stop_process(proc)
