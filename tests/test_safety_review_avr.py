"""The adversarial review of the safety paths (test_safety_review.py) on the AVR firmware in
simavr."""

from __future__ import annotations

import os
import struct
import threading
import time
import tty
from collections.abc import Iterator
from pathlib import Path

import pytest

from missing_link.host.board import Board
from missing_link.j2a import SOF, encode_frame
from missing_link.transport import open_transport

from .helpers import AvrSim, wait_for
from .test_safety_review import (
    H0,
    SET,
    _at,
    _keep_talking,
    _moves_then_goes_limp,
    _refuses_what_is_not_timeable,
    _timed_map,
)

# ---- the AVR firmware ----------------------------------------------------------------------------


@pytest.fixture
def rig(avr_build: Path) -> Iterator[AvrSim]:
    sim = AvrSim(avr_build, avr_build / "uno_rig" / "firmware.elf")
    try:
        yield sim
    finally:
        sim.close()


def _avr_pulse(rig: AvrSim) -> float:
    return float(rig.ctl("pulse").split()[1])


def _avr_now(rig: AvrSim) -> int:
    return int(rig.ctl("stats").split()[2])


@pytest.mark.slow
@pytest.mark.avr
def test_avr_only_actuator_calls_and_goodbye_can_be_timed(rig: AvrSim) -> None:
    """(before: a timed a2jGetMapping or a2jAt overran a 16-byte buffer on the stack and the
    CPU stopped; a timed a2jMany called address 0: a reset that made nothing safe)"""
    board = Board(open_transport(rig.url), timeout=5.0)
    try:
        board.handshake()
        epoch = board.properties["clock.epoch"]
        board.configure({"servo.safe": "limp"})
        _refuses_what_is_not_timeable(board)
        _timed_map(board)
        board.call_ok("a2jAt", _at(board.index, "a2j_set_servo", H0 + 200_000_000, b"\xc4"))
        board.call_ok("a2jAt", _at(board.index, "a2jGoodbye", H0 + 600_000_000))
        assert _moves_then_goes_limp(board, lambda: _avr_pulse(rig))
        done = struct.unpack("<BIIII", board.call_ok("a2jAlignInfo"))[3]
        assert done == 2
    finally:
        board.close()
    assert rig.proc.poll() is None
    again = Board(open_transport(rig.url), timeout=5.0)
    try:
        again.handshake(describe=False)
        assert again.properties["clock.epoch"] == epoch, "the board reset"
    finally:
        again.close()


@pytest.mark.slow
@pytest.mark.avr
def test_avr_a_timed_call_refused_when_due_is_counted_and_said(rig: AvrSim) -> None:
    board = Board(open_transport(rig.url), timeout=5.0)
    lines: list[str] = []
    board.on_log(lambda line: lines.append(line.text))
    try:
        board.handshake()
        _timed_map(board)
        board.call_ok("a2jAt", _at(board.index, "a2j_set_servo", H0 + 400_000_000, b"\xc4"))
        board.configure({"servo.enabled": False})  # disabled meanwhile
        _keep_talking(board, 0.8)
        done, refused = struct.unpack("<BIIII", board.call_ok("a2jAlignInfo"))[3:5]
        assert (done, refused) == (0, 1) and _avr_pulse(rig) == 0  # (before: done 1)
        assert wait_for(lambda: any("refused when due: a2j_set_servo" in t for t in lines), 5)
    finally:
        board.close()


def _raw_line(rig: AvrSim) -> int:
    fd = os.open(rig.url[len("serial://") :], os.O_RDWR | os.O_NOCTTY)
    tty.setraw(fd)
    return fd


@pytest.mark.slow
@pytest.mark.avr
def test_avr_a_stream_of_cut_frames_does_not_keep_the_failsafe_from_tripping(
    rig: AvrSim,
) -> None:
    """12 00 12 00 ...: an F2 reply of 7 bytes for every 2 bytes in.  main.c emptied the
    receive ring before each failsafe_poll: the stream kept it in there for ever."""
    board = Board(open_transport(rig.url), timeout=5.0)
    try:
        board.handshake()
        board.configure({"servo.safe": "limp"})
        servo = board.index["a2j_set_servo"]
    finally:
        board.close()
    fd = _raw_line(rig)
    stop = threading.Event()

    def drain() -> None:
        while not stop.is_set():
            try:
                os.read(fd, 4096)
            except OSError:
                return

    t = threading.Thread(target=drain, daemon=True)
    t.start()
    try:
        os.write(fd, encode_frame(SOF, 1, servo, struct.pack("<b", SET)))  # the last intact one
        t0 = _avr_now(rig)
        while _avr_now(rig) - t0 < 2_000_000:  # 2 s of simulated time, 4 x failsafe_ms
            os.write(fd, bytes.fromhex("1200") * 256)
        assert _avr_pulse(rig) == 0, "no failsafe after 2 s of cut frames"
    finally:
        stop.set()
        os.close(fd)
        t.join(5)


@pytest.mark.slow
@pytest.mark.avr
@pytest.mark.parametrize("seed", ["error", "zero"], ids=["F0 heard back", "a reply of 0"])
def test_avr_its_own_frames_heard_back_do_not_keep_the_failsafe_alive(
    rig: AvrSim, seed: str
) -> None:
    board = Board(open_transport(rig.url), timeout=5.0)
    try:
        board.handshake()
        board.configure({"servo.safe": "limp"})
        servo = board.index["a2j_set_servo"]
    finally:
        board.close()
    fd = _raw_line(rig)
    stop = threading.Event()

    def loop_back() -> None:  # every byte the board sends comes back to it
        while not stop.is_set():
            try:
                os.write(fd, os.read(fd, 4096))
            except OSError:
                return

    t = threading.Thread(target=loop_back, daemon=True)
    t.start()
    try:
        os.write(fd, encode_frame(SOF, 1, servo, struct.pack("<b", SET)))  # its reply: 0
        if seed == "error":
            os.write(fd, encode_frame(SOF, 2, 0xF0, b""))
        t0 = _avr_now(rig)
        while _avr_now(rig) - t0 < 2_000_000:  # 2 s of simulated time, 4 x failsafe_ms
            time.sleep(0.05)
        assert _avr_pulse(rig) == 0, "the echo kept the failsafe alive"
    finally:
        stop.set()
        os.close(fd)
        t.join(5)
