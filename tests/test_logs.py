"""Logs cannot be flooded (logs.py): every logger the daemon runs goes through one filter at the
root that cleans and rate-limits, libraries' tracebacks folded into their line; and a daemon run
from the command line, its Foxglove port hit with 200 bad frame headers and with more
connections than it has file descriptors, writes a bounded stderr."""

from __future__ import annotations

import base64
import logging
import os
import resource
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from missing_link.logs import SafeLog, counts, template

from .helpers import board_process, wait_for


def record(
    name: str, msg: str, *args: object, exc: BaseException | None = None
) -> logging.LogRecord:
    info = (type(exc), exc, exc.__traceback__) if exc is not None else None
    return logging.LogRecord(name, logging.ERROR, "", 0, msg, args or None, info)


def raised(text: str) -> BaseException:
    try:
        raise ValueError(text)
    except ValueError as e:
        return e


def test_messages_formatted_before_they_were_logged_count_as_one_kind() -> None:
    """asyncio logs "Task exception was never retrieved" with the task's repr in the text:
    a new message every time, unless the numbers are taken out."""
    a = record("asyncio", "Task exception was never retrieved\nfuture: <Task name='Task-997'>")
    b = record("asyncio", "Task exception was never retrieved\nfuture: <Task name='Task-12'>")
    assert template(a) == template(b) == "Task exception was never retrieved"
    assert template(record("x", "bad name %r", "a")) == "bad name %r"
    now = [0.0]
    f = SafeLog(clock=lambda: now[0])
    shown = [
        f.filter(record("asyncio", f"socket.accept() out of system resource fd={k}"))
        for k in range(50)
    ]
    assert sum(shown) == 5


def test_one_logger_is_held_back_whatever_it_says() -> None:
    now = [0.0]
    f = SafeLog(clock=lambda: now[0], per_logger=30)
    before = SafeLog.held.get("websockets.server", 0)
    shown = [
        f.filter(record("websockets.server", f"kind {chr(65 + k % 26)} %s", k)) for k in range(200)
    ]
    assert sum(shown) == 30
    assert SafeLog.held["websockets.server"] - before == 170
    assert "websockets.server" in counts()["held_back_from"]
    now[0] = 61.0  # a new window: it may speak again
    assert f.filter(record("websockets.server", "kind A %s", 0))


def test_library_tracebacks_fold_and_ours_are_cleaned() -> None:
    f = SafeLog(clock=lambda: 0.0)
    folded = SafeLog.folded
    lib = record("websockets.server", "opening handshake failed", exc=raised("bad\x1b[2J\nforged"))
    assert f.filter(lib) and lib.exc_info is None and SafeLog.folded == folded + 1
    line = logging.Formatter("%(message)s").format(lib)
    assert line == "opening handshake failed (ValueError: badforged)"  # (escapes whole: text.py)
    ours = record(
        "missing_link.daemon.session.session", "session failed", exc=raised("x\x1b]0;t\x07y")
    )
    assert f.filter(ours)
    text = logging.Formatter("%(message)s").format(ours)
    assert "Traceback (most recent call last)" in text and "ValueError: xy" in text
    assert "\x1b" not in text and "\x07" not in text


def upgrade_then(port: int, frame: bytes) -> bool:
    """A WebSocket upgrade, then ``frame``: whether the upgrade was answered (101)."""
    key = base64.b64encode(os.urandom(16)).decode()
    head = (
        f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\n"
        f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
        "Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n"
    )
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=5) as s:
            s.sendall(head.encode())
            answer = s.recv(4096)
            s.sendall(frame)
            return answer.startswith(b"HTTP/1.1 101")
    except OSError:
        return False


@pytest.mark.slow
def test_a_flooded_daemon_writes_a_bounded_stderr(tmp_path: Path) -> None:
    """200 tiny bad frame headers made 4,200 lines of tracebacks (14,000 through the old gate
    here) and fd exhaustion 66 MB of stderr in 100 s.  Now each writes a few lines."""
    cfg = tmp_path / "fox.toml"
    cfg.write_text("[foxglove]\nport = 0\n")
    limit = 96  # descriptors: the daemon starts with ~40; the flood holds more than the rest

    def low_fd_limit() -> None:
        resource.setrlimit(resource.RLIMIT_NOFILE, (limit, limit))

    with board_process("--sim", "thesis") as url:
        env = {**os.environ, "MISSING_LINK_CONTROL": str(tmp_path / "control.sock")}
        p = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "missing_link",
                "run",
                url,
                "--config",
                str(cfg),
                "-p",
                "foxglove",
            ],
            stderr=subprocess.PIPE,
            stdout=subprocess.DEVNULL,
            text=True,
            env=env,
            preexec_fn=low_fd_limit,
        )
        try:
            assert p.stderr is not None
            port = 0
            while not port:
                line = p.stderr.readline()
                assert line, "the daemon ended before its Foxglove view listened"
                if "foxglove at ws://" in line:
                    port = int(line.rsplit(":", 1)[1])
            answered = sum(upgrade_then(port, b"\xff\xff") for _ in range(200))
            held = []
            for _ in range(2 * limit):  # more than it has descriptors: its accepts fail
                try:
                    held.append(socket.create_connection(("127.0.0.1", port), timeout=2))
                except OSError:
                    break
            # it retries its accept: a few rounds of EMFILE, one of them refused
            refused = wait_for(lambda: not upgrade_then(port, b""), 3, step=0)
            for s in held:
                s.close()
            assert upgrade_then(port, b"\x88\x80\0\0\0\0")  # (it recovers: a clean close)
        finally:
            p.send_signal(signal.SIGINT)
            _out, err = p.communicate(timeout=30)
    lines = [x for x in err.splitlines() if x.strip()]
    assert answered >= 150 and refused >= 1, (answered, refused, err[-2000:])
    assert "Traceback" not in err
    assert len(lines) <= 60 and len(err) <= 12_000, (len(lines), len(err), err[-3000:])
