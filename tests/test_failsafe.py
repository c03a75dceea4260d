"""The failsafe (board/failsafe.py; the daemon's side: daemon/session/failsafe.py) on the Python
runtime: the timer and goodbye on a board runtime with a clock we turn, and a real daemon process
that is SIGKILLed while a virtual board process goes on (the MicroPython and AVR runtimes:
tests/test_rover.py, tests/test_avr_rover.py)."""

from __future__ import annotations

import os
import signal
import struct
import subprocess
import time
from concurrent.futures import Future
from pathlib import Path
from typing import Any, cast

import pytest

from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config
from missing_link.daemon.session.failsafe import goodbye, keepalive_s
from missing_link.host.board import Board
from missing_link.testing import FakeBoardClock
from missing_link.testing import call_runtime as call
from missing_link.virtual import make_sim

from .helpers import ML, board_process, ml, wait_for


def test_an_actuator_goes_safe_after_its_silence_and_on_goodbye() -> None:
    clock = FakeBoardClock()
    rt = make_sim("thesis", 3, clock=clock)
    servo = next(t for t in rt.transducers if t.name == "servo").driver
    assert call(rt, "a2jConfigKeys", b"")[0] is not None
    call(rt, "a2j_set_servo", b"\x28")  # a frame from the host: 40
    for k in range(50):  # the servo moves there, the host talking every 200 ms
        clock.us += 20_000
        rt.poll()
        if k % 10 == 9:
            call(rt, "a2jEcho", b"")
    rt.take_frames()
    assert servo.target == servo.position != 0
    call(rt, "a2jEcho", b"")  # the host's last frame
    clock.us += 450_000
    rt.poll()
    assert rt.failsafe.trips == 0  # not yet: 450 < 500 ms (a J2A read would be a frame)
    clock.us += 100_000
    rt.poll()
    assert rt.failsafe.trips == 1
    clock.us += 20_000
    _opcode, info = call(rt, "a2jFailsafe")
    trips, age = struct.unpack("<II", info)
    assert trips == 1 and age == 20
    debug = call(rt, "a2jDebug")[1].decode()
    assert "failsafe: servo safe (no frame from the host for 550 ms);" in debug
    clock.us += 5_000_000
    rt.poll()  # a new silence (since the reads above), but the servo was not commanded again:
    assert rt.failsafe.trips == 1  # it is safe already
    # the keys: failsafe_ms is a run-time key of every guarded actuator, safe the servo's
    names = [k.name for k in rt.config.keys]  # type: ignore[attr-defined]
    assert "servo.failsafe_ms" in names and "servo.safe" in names
    rt.config.apply([(next(k for k in rt.config.keys if k.name == "servo.safe"), "limp")])  # type: ignore[attr-defined]
    call(rt, "a2j_set_servo", b"\x10")
    assert not servo.limp
    assert call(rt, "a2jGoodbye") == (0, b"")  # at once
    assert servo.limp
    assert "the host said goodbye" in call(rt, "a2jDebug")[1].decode()


@pytest.mark.slow
def test_the_daemon_keeps_a_quiet_link_alive() -> None:
    """Nothing commanded for 2 s: the daemon's keepalive (a third of the shortest failsafe_ms)
    keeps the board from tripping; the status shows the board's count."""
    with (
        board_process("--sim", "thesis") as url,
        Daemon(Config(boards=[BoardSpec(url, timeout=2.0)], diagnostics_period=0.2)) as d,
    ):
        assert d.wait_until_up(10)
        s = d.sessions[0]
        assert keepalive_s(s.board, s.run_config.values) == 0.5 / 3
        time.sleep(2.0)
        assert wait_for(lambda: "failsafe_trips" in d.status()[0])
        assert d.status()[0]["failsafe_trips"] == 0


@pytest.mark.slow
def test_a_killed_daemon_trips_the_failsafe(tmp_path: Path) -> None:
    with board_process("--sim", "thesis") as url:
        cfg = tmp_path / "d.toml"
        cfg.write_text(
            f'[daemon]\npublishers = ["bus"]\ncontrol = "{tmp_path}/c.sock"\n'
            f'[[board]]\nurl = "{url}"\n[boards.thesis.config]\n"servo.safe" = "limp"\n'
        )
        p = subprocess.Popen(
            [*ML, "run", "--config", str(cfg)],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        env = {**os.environ, "MISSING_LINK_CONTROL": f"{tmp_path}/c.sock"}
        try:
            servo = ("call", "thesis", "a2j_set_servo", "--value", "40")
            assert wait_for(lambda: ml(*servo, timeout=30, env=env).returncode == 0, 30)
            time.sleep(0.5)
            p.send_signal(signal.SIGKILL)
            p.wait(10)
            time.sleep(1.0)  # > 500 ms of silence
        finally:
            if p.poll() is None:
                p.kill()
                p.wait(5)
        with Board.open(url) as board:  # the next host asks what happened
            trips, age = struct.unpack("<II", board.call_ok("a2jFailsafe"))
            debug = board.call_ok("a2jDebug").decode()
        assert trips == 1 and 300 <= age < 5000
        assert "failsafe: servo safe (no frame from the host for" in debug


class _UnansweredBoard:
    """A board whose link closes under the goodbye: the call is never answered."""

    index = {"a2jGoodbye": 0}
    alive = True

    def __init__(self) -> None:
        self.calls = 0

    def call_future(self, name: str, payload: bytes = b"", timeout: float | None = None) -> Any:
        self.calls += 1
        return Future()


def test_a_goodbye_never_answered_neither_hangs_nor_raises() -> None:
    board = _UnansweredBoard()
    goodbye(cast(Board, board))  # returns (stopping goes on: the board trips on its own)
    assert board.calls == 1
