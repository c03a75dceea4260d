"""The command line's own checks, in process: numbers that reach a board or the daemon are
finite and in range (issue 33: ``--timeout 1e308``, ``Infinity`` or ``NaN`` held a dead board
"up"), every usage error is one line with exit 2 (docs/cli.md), and the parser built for one
command is the whole parser's for that command."""

from __future__ import annotations

import argparse
import re
import socket
import struct
from pathlib import Path
from typing import Any

import pytest

from missing_link.cli.commands import COMMANDS
from missing_link.cli.common import MAX_TIMEOUT_S
from missing_link.cli.main import build_parser, main
from missing_link.cli.talk import value_payload
from missing_link.descriptors import Transducer
from missing_link.errors import ConfigError

ONE_BOARD = ("info", "call", "listen", "sync", "config", "create-msgs")


def usage_error(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """The one line ``argv`` is refused with (exit 2, nothing on stdout)."""
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 2
    out, err = capsys.readouterr()
    assert out == ""
    (line,) = err.splitlines()
    assert line.startswith("missing-link: error: ")
    return line


def command_line(command: str, url: str, *more: str) -> list[str]:
    args = {"call": [url, "a2jEcho"], "create-msgs": [url, "--out", "/nonexistent"]}
    return [command, *args.get(command, [url]), *more]


@pytest.fixture
def listener() -> object:
    """A TCP port that accepts and counts connections: a refused option must connect to nothing."""
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    sock.listen(8)
    sock.setblocking(False)
    yield sock
    sock.close()


def accepted(sock: socket.socket) -> int:
    n = 0
    while True:
        try:
            conn, _ = sock.accept()
        except BlockingIOError:
            return n
        conn.close()
        n += 1


@pytest.mark.parametrize("command", ONE_BOARD)
@pytest.mark.parametrize(
    ("value", "words"),
    [
        ("1e308", "over 60 s, the most allowed"),
        ("Infinity", "not a finite number"),
        ("inf", "not a finite number"),
        ("NaN", "not a finite number"),
        ("-1", "must be a number > 0"),
        ("0", "must be a number > 0"),
        ("60.5", "over 60 s, the most allowed"),
        ("soon", "is not a number"),
    ],
)
def test_a_timeout_out_of_range_is_refused_before_anything_is_sent(
    command: str,
    value: str,
    words: str,
    listener: socket.socket,
    capsys: pytest.CaptureFixture[str],
) -> None:
    url = f"tcp://127.0.0.1:{listener.getsockname()[1]}"
    line = usage_error(command_line(command, url, "--timeout", value), capsys)
    assert "argument --timeout" in line and words in line
    assert f"missing-link {command} --help" in line
    assert accepted(listener) == 0  # nothing reached the board (or a daemon)


def test_the_longest_timeout_allowed_is_taken() -> None:
    args = build_parser().parse_args(["call", "tcp://h:1", "a2jEcho", "--timeout", "60"])
    assert args.timeout == MAX_TIMEOUT_S
    args = build_parser().parse_args(["call", "tcp://h:1", "a2jEcho", "--timeout", "0.05"])
    assert args.timeout == 0.05


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["listen", "tcp://h:1", "--duration", "nan"], "argument --duration: nan is not a finite"),
        (["listen", "tcp://h:1", "--duration", "1e308"], "--duration: 1e308 is over 31536000 s"),
        (["sync", "tcp://h:1", "--period", "inf"], "--period: inf is not a finite number"),
        (["sync", "tcp://h:1", "--period", "0"], "--period: 0 must be a number > 0"),
        (["run", "tcp://h:1", "--wait-up", "NaN"], "--wait-up: NaN is not a finite number"),
        (["run", "tcp://h:1", "--duration", "-1"], "--duration: -1 must be a number >= 0"),
        (["demo", "--duration", "nan"], "--duration: nan is not a finite number"),
        (["board", "--sim", "rate", "--listen", "pty", "--rate", "nan"], "--rate: nan is not"),
        (
            ["board", "--sim", "rate", "--listen", "pty", "--rate", "1e9"],
            "1e9 is over 100000 Hz, the most allowed",
        ),
        (["board", "--sim", "rate", "--listen", "pty", "--rate", "0"], "--rate: 0 must be"),
        (["board", "--sim", "thesis", "--listen", "pty", "--clock-skew-ppm", "inf"], "finite"),
        (["board", "--sim", "thesis", "--listen", "pty", "--reset-at", "nan"], "finite"),
        (["relay", "tcp://h:1", "--delay-ms", "inf"], "--delay-ms: inf is not a finite"),
        (["relay", "tcp://h:1", "--drop", "nan"], "--drop: nan is not a finite number"),
        (["relay", "tcp://h:1", "--blackhole-after", "inf"], "--blackhole-after: inf is not"),
    ],
)
def test_every_duration_and_rate_is_finite_and_in_range(
    argv: list[str], words: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert words in usage_error(argv, capsys)


def test_other_usage_errors_are_one_line_too(capsys: pytest.CaptureFixture[str]) -> None:
    assert "required: COMMAND" in usage_error([], capsys)
    assert "invalid choice: 'frob'" in usage_error(["frob"], capsys)
    assert "required: url, name" in usage_error(["call"], capsys)
    assert "required: ACTION" in usage_error(["key"], capsys)
    assert "unrecognized arguments: --nope" in usage_error(["info", "tcp://h:1", "--nope"], capsys)


def help_of(parser: argparse.ArgumentParser, command: str) -> str:
    sub = next(a for a in parser._actions if a.dest == "command")
    return str(sub.choices[command].format_help())  # type: ignore[attr-defined]


@pytest.mark.parametrize("command", [c.name for c in COMMANDS])
def test_the_parser_for_one_command_is_the_whole_parsers(command: str) -> None:
    assert help_of(build_parser(command), command) == help_of(build_parser(), command)


def test_a_command_line_runs_the_command_it_names(tmp_path: Path) -> None:
    key = tmp_path / "k.key"
    assert main(["key", "new", str(key)]) == 0
    assert len(key.read_text().strip()) == 64


class _Board:
    """What ``value_payload`` reads of a board: its name and its transducers."""

    name = "rover"

    def __init__(self, *transducers: Transducer) -> None:
        self.transducers = list(transducers)


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("1e308", "beyond a float"),
        ("nan", "not finite"),
        ("inf", "not finite"),
        ("-inf", "not finite"),
        ("fast", "takes a float"),
    ],
)
def test_a_value_an_actuator_cannot_take_is_one_line(text: str, words: str) -> None:
    stepper = Transducer("wheel", 0, "wheel", "A4988", 1, "float", float("nan"))
    stepper.options.update(kind="actuator", call="a2j_set_wheel")
    with pytest.raises(ConfigError, match=words):
        value_payload(_Board(stepper), "a2j_set_wheel", text)
    assert value_payload(_Board(stepper), "a2j_set_wheel", "2.5") == struct.pack("<f", 2.5)


EXPECTED = "expected a number in 0.1..26"


def test_a_config_value_beyond_a_float32_is_one_line(
    serve: Any, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """``dist_ir.rate_hz=1e308`` overflowed a float32 pack: a traceback, not exit 2.  (Five
    commands back to back against one virtual board: one that connected in the turn the last
    one closed was turned away as a second host, 1 run in 5, until the server read the close
    first.)"""
    monkeypatch.setenv("MISSING_LINK_CONTROL", str(tmp_path / "no-daemon.sock"))
    url = serve("thesis", listen="tcp://127.0.0.1:0").url
    for value in ("1e308", "-1e39", "nan", "inf"):
        code = main(["config", url, f"dist_ir.rate_hz={value}"])
        (line,) = capsys.readouterr().err.splitlines()
        assert code == 2, line
        assert (
            line
            == f"missing-link: error: dist_ir.rate_hz = '{value}': expected a number in 0.1..26"
        )
    assert main(["config", url]) == 0
    assert re.search(r"^dist_ir\.rate_hz += 25$", capsys.readouterr().out, re.M)  # unchanged
