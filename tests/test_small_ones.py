"""Small things a new user met off the demo path (issue 45.9): a wrong port said once, then
retried quietly; a port another ``missing-link run`` holds says so; ``call --value`` says what
the answer means.  (The demo summary's legend: tests/test_cli.py.)"""

from __future__ import annotations

import io
import os
import subprocess
import sys
from collections.abc import Callable
from typing import Any

import pytest
import serial

from missing_link.cli.main import main
from missing_link.daemon import BoardSpec, Config, Daemon
from missing_link.errors import TransportBroken
from missing_link.publishers.console import ConsolePublisher
from missing_link.transport.serialport import cannot_open, open_serial

from .helpers import wait_for

Serve = Callable[..., Any]


def test_a_missing_port_is_one_plain_line() -> None:
    """pyserial's text doubled the errno and the path."""
    with pytest.raises(serial.SerialException) as e:
        serial.Serial("/dev/ttyNOPE", exclusive=True)
    assert cannot_open("/dev/ttyNOPE", e.value) == (
        "cannot open /dev/ttyNOPE: no such device (unplugged? another name?)"
    )


def test_a_wrong_port_is_said_once_and_retried_quietly(caplog: pytest.LogCaptureFixture) -> None:
    out = io.StringIO()
    cfg = Config(boards=[BoardSpec("serial:///dev/ttyNOPE")], diagnostics_period=0.02,
                 backoff_min=0.01, backoff_max=0.05)  # fmt: skip
    with Daemon(cfg, [ConsolePublisher(out=out)]) as d:
        assert wait_for(lambda: d.status()[0]["failures"] >= 10, 10)  # (retried, with backoff)
        rounds = d.status()[0]["failures"]
    # (and, when a round of /diagnostics came before the first attempt failed, its state then)
    lines = [x for x in out.getvalue().splitlines() if not x.endswith(": connecting: connecting")]
    assert len(lines) == 1 and lines[0].endswith(
        "/diagnostics serial:///dev/ttyNOPE: backoff: cannot open /dev/ttyNOPE: no such device "
        "(unplugged? another name?)"
    ), lines  # (before: one a round, on stdout)
    said = [r.getMessage() for r in caplog.records if "ttyNOPE" in r.getMessage()]
    assert len(said) == 1 and "[Errno" not in said[0], said
    assert rounds >= 10


@pytest.mark.slow
def test_a_port_another_run_holds_says_so() -> None:
    board = subprocess.Popen(
        [sys.executable, "-m", "missing_link", "board", "--sim", "thesis", "--listen", "pty"],
        stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    assert board.stdout is not None
    url = board.stdout.readline().split()[1]
    run = subprocess.Popen(
        [sys.executable, "-m", "missing_link", "run", url, "-p", "bus", "--duration", "60"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        env={**os.environ, "MISSING_LINK_CONTROL": ""},
    )  # fmt: skip
    try:
        assert run.stderr is not None
        assert "running 1 board(s)" in run.stderr.readline()
        held: list[str] = []

        def refused() -> bool:
            try:
                open_serial(url, {}).close()
            except TransportBroken as e:
                held.append(str(e))
                return True
            return False

        assert wait_for(refused, 10)
        path = url.removeprefix("serial://")
        assert held[-1].startswith(f"{url}: {path} is held by another missing-link run (pid "), held
        assert f"{run.pid}: missing-link run {url} -p bus" in held[-1], held
    finally:
        run.terminate()
        run.wait(10)
        board.terminate()
        board.wait(10)


def test_a_call_with_a_value_says_what_the_answer_means(
    serve: Serve, capsys: pytest.CaptureFixture[str]
) -> None:
    server = serve("thesis")
    assert main(["call", server.url, "a2j_set_servo", "--value", "40"]) == 0
    assert capsys.readouterr().out.splitlines()[-1] == (
        "  means OK: servo took 40 (28.35 deg), as send() of its command topic would send it"
    )
    assert main(["call", server.url, "a2jEcho", "--hex", "01"]) == 0
    assert "means OK (a2jEcho's own code: the payload came back)" in capsys.readouterr().out
    assert main(["call", server.url, "setTrigger", "--hex", "01"]) == 1
    assert "means refused: the function's failure (expects u64" in capsys.readouterr().out
