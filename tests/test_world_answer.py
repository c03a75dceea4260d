"""``missing-link world URL`` takes what answers at the URL as untrusted (the world attacked,
issue 43): whatever listens there may answer, and an answer of another shape (a list, a state
without its numbers, a number that is text, a megabyte and more) was a KeyError, AttributeError
or ValueError traceback; now it is one line, exit 1.  A world's part names and its errors are
printed without their escape sequences."""

from __future__ import annotations

import json
import socket
import threading
from pathlib import Path
from typing import Any

import pytest

from .helpers import ml

pytestmark = pytest.mark.slow

STATE = {"t_s": 1.5, "x_m": 0.25, "y_m": -1, "yaw_deg": 90, "speed_m_s": 0, "turn_dps": 0,
         "battery_v": 8.1, "bumps": 2, "blocked": [], "failed": []}  # fmt: skip


def served(path: Path, answer: bytes) -> threading.Thread:
    """One connection on the unix socket ``path`` answered with ``answer``."""
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    sock.bind(str(path))
    sock.listen(1)
    sock.settimeout(60)

    def serve() -> None:
        with sock:
            conn, _ = sock.accept()
            with conn:
                conn.recv(4096)
                try:
                    conn.sendall(answer)
                except BrokenPipeError:
                    pass  # (the CLI stops reading beyond an answer's size)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    return thread


def world_state(tmp_path: Path, answer: bytes) -> Any:
    thread = served(tmp_path / "w.sock", answer)
    r = ml("world", f"unix://{tmp_path}/w.sock", "state", timeout=60)
    thread.join(10)
    return r


@pytest.mark.parametrize(
    "answer",
    [
        b"[1, 2]\n",
        b'{"state": {}}\n',
        b'{"state": [1]}\n',
        json.dumps({"state": {**STATE, "t_s": "a"}}).encode() + b"\n",
        json.dumps({"state": {**STATE, "blocked": [1]}}).encode() + b"\n",
        b'{"state": {"t_s": "' + b"x" * (2 << 20) + b'"}}\n',
        b"NaN\n",
    ],
    ids=["list", "empty-state", "state-list", "text-number", "name-number", "2MB", "NaN"],
)
def test_an_answer_not_a_worlds_is_one_line_exit_1(tmp_path: Path, answer: bytes) -> None:
    r = world_state(tmp_path, answer)
    assert r.returncode == 1 and "not a world's answer" in r.stderr, r.stderr
    assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr


def test_a_worlds_names_and_errors_are_printed_without_escapes(tmp_path: Path) -> None:
    names = {**STATE, "blocked": ["\x1b]0;title\x07sonar"], "failed": ["\x1b[2Jimu"]}
    r = world_state(tmp_path, json.dumps({"state": names}).encode() + b"\n")
    assert r.returncode == 0, r.stderr
    assert "blocked sonar  failed imu" in r.stdout and "\x1b" not in r.stdout, r.stdout
    (tmp_path / "w.sock").unlink()
    r = world_state(tmp_path, json.dumps({"error": "\x1b[2J\x1b]0;x\x07no such part"}).encode())
    assert r.returncode == 2 and "\x1b" not in r.stderr and "no such part" in r.stderr, r.stderr
