"""The adversarial review of the safety paths (test_safety_review.py) on the MicroPython
firmware under real MicroPython (node)."""

from __future__ import annotations

import socket
import struct
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from missing_link.host.board import Board
from missing_link.j2a import SOF, Frame, FrameDecoder, FrameKind, encode_frame
from missing_link.transport import open_transport

from .helpers import FirmwareSim, wait_for
from .test_safety_review import (
    H0,
    NOT_TIMED,
    SET,
    _at,
    _keep_talking,
    _moves_then_goes_limp,
    _refuses_what_is_not_timeable,
    _timed_map,
)

ROOT = Path(__file__).resolve().parent.parent
RIG = ROOT / "examples" / "boards" / "thesis-rig.py"


# ---- the MicroPython firmware ----------------------------------------------------------------


@pytest.fixture
def mpy() -> Iterator[FirmwareSim]:
    s = FirmwareSim(RIG)
    try:
        yield s
    finally:
        s.close()


def _pulse(sim: FirmwareSim) -> float:
    return float(sim.ctl("result = WORLD.pulse_us(15)") or 0.0)


@pytest.mark.slow
@pytest.mark.micropython
def test_micropython_only_actuator_calls_and_goodbye_can_be_timed(mpy: FirmwareSim) -> None:
    board = Board(open_transport(mpy.url), timeout=5.0)
    try:
        board.handshake()
        board.configure({"servo.safe": "limp"})
        _refuses_what_is_not_timeable(board)
        assert mpy.ctl("result = (rt.timing.refused, rt.timing.pending())") == (len(NOT_TIMED), 0)
        _timed_map(board)
        board.call_ok("a2jAt", _at(board.index, "a2j_set_servo", H0 + 200_000_000, b"\xc4"))
        board.call_ok("a2jAt", _at(board.index, "a2jGoodbye", H0 + 600_000_000))
        assert _moves_then_goes_limp(board, lambda: _pulse(mpy))
        assert mpy.ctl("result = (rt.timing.done, rt.failsafe.trips)") == (2, 1)
    finally:
        board.close()


@pytest.mark.slow
@pytest.mark.micropython
def test_micropython_a_timed_call_refused_when_due_is_counted(mpy: FirmwareSim) -> None:
    board = Board(open_transport(mpy.url), timeout=5.0)
    try:
        board.handshake()
        _timed_map(board)
        board.call_ok("a2jAt", _at(board.index, "a2j_set_servo", H0 + 400_000_000, b"\xc4"))
        board.configure({"servo.enabled": False})  # disabled meanwhile
        _keep_talking(board, 0.8)
        assert wait_for(lambda: mpy.ctl("result = rt.timing.pending()") == 0, 10)
        done, refused = struct.unpack("<BIIII", board.call_ok("a2jAlignInfo"))[3:5]
        assert (done, refused) == (0, 1) and _pulse(mpy) == 0  # (before: done 1)
    finally:
        board.close()


@pytest.mark.slow
@pytest.mark.micropython
@pytest.mark.parametrize("seed", ["error", "zero"], ids=["F0 heard back", "a reply of 0"])
def test_micropython_its_own_frames_heard_back_do_not_keep_the_failsafe_alive(
    mpy: FirmwareSim, seed: str
) -> None:
    board = Board(open_transport(mpy.url), timeout=5.0)
    try:
        board.handshake()
        board.configure({"servo.safe": "limp"})
        servo = board.index["a2j_set_servo"]
    finally:
        board.close()
    host, port = mpy.url[len("tcp://") :].split(":")
    line = socket.create_connection((host, int(port)), timeout=5)
    stop = threading.Event()
    echoed = [0]

    def loop_back() -> None:  # every byte the board sends comes back to it
        line.settimeout(0.1)
        while not stop.is_set():
            try:
                data = line.recv(4096)
            except TimeoutError:
                continue
            except OSError:
                return
            if not data:
                return
            echoed[0] += len(data)
            line.sendall(data)

    t = threading.Thread(target=loop_back, daemon=True)
    t.start()
    try:
        line.sendall(encode_frame(SOF, 1, servo, struct.pack("<b", SET)))  # its reply: 0
        if seed == "error":
            line.sendall(encode_frame(SOF, 2, 0xF0, b""))
        assert wait_for(lambda: echoed[0] > 0, 10)
        assert wait_for(lambda: _pulse(mpy) == 0, 5), "the echo kept the failsafe alive"
    finally:
        stop.set()
        t.join(5)
        line.close()


@pytest.mark.slow
@pytest.mark.micropython
def test_micropython_a_frame_dropped_after_silence_leaves_no_break_behind(
    mpy: FirmwareSim,
) -> None:
    host, port = mpy.url[len("tcp://") :].split(":")
    with socket.create_connection((host, int(port)), timeout=5) as line:
        tail = b"\x03\x03repl\r"
        line.sendall(bytes([SOF, 5, 4, len(tail) + 1]))  # a frame's head, then silence
        assert _reply(line, 5).opcode == 0xF2  # the board dropped it (an F2) ...
        line.sendall(tail + b"\x00")  # ... and then its rest comes
        line.sendall(encode_frame(SOF, 6, 4, b"on"))  # an a2jEcho (index 4)
        try:
            answered = _reply(line, 6).payload == b"on"
        except OSError:  # (the firmware stopped: no answer)
            answered = False
    assert mpy.ctl("result = rt.breaks") == 0 and answered  # (before: it stopped, for the REPL)


@pytest.mark.slow
@pytest.mark.micropython
def test_micropython_a_stream_of_cut_frames_does_not_keep_the_failsafe_from_tripping(
    mpy: FirmwareSim,
) -> None:
    """As on AVR: 12 00 12 00 ... (an F2 for every 2 bytes) for 2 s of board time after the
    host's last command: the failsafe trips (damaged frames are no host)."""
    board = Board(open_transport(mpy.url), timeout=5.0)
    try:
        board.handshake()
        board.configure({"servo.safe": "limp"})
        board.call_ok("a2j_set_servo", struct.pack("<b", SET))
    finally:
        board.close()
    assert _pulse(mpy) == 1217
    host, port = mpy.url[len("tcp://") :].split(":")
    with socket.create_connection((host, int(port)), timeout=5) as line:
        stop = threading.Event()

        def drain() -> None:
            while not stop.is_set():
                try:
                    if not line.recv(65536):
                        return
                except OSError:
                    return

        t = threading.Thread(target=drain, daemon=True)
        t.start()
        try:
            t0 = mpy.ctl("result = rt.clock()")
            while mpy.ctl("result = rt.clock()") - t0 < 2_000_000:
                line.sendall(bytes.fromhex("1200") * 256)
            assert _pulse(mpy) == 0 and mpy.ctl("result = rt.failsafe.trips") == 1
        finally:
            stop.set()
            line.shutdown(socket.SHUT_RDWR)
            t.join(5)


@pytest.mark.slow
@pytest.mark.micropython
def test_micropython_the_break_after_a_dropped_frame_and_quiet_still_stops_it(
    mpy: FirmwareSim,
) -> None:
    """What `flash` does on a port whose last owner left a frame half sent: once the line has
    been quiet (the frame dropped, its rest skipped), the break is recognised."""
    host, port = mpy.url[len("tcp://") :].split(":")
    with socket.create_connection((host, int(port)), timeout=5) as line:
        line.sendall(bytes([SOF, 7, 4, 9]))  # a frame's head, then silence
        assert _reply(line, 7).opcode == 0xF2  # dropped
        assert wait_for(lambda: mpy.ctl("result = rt.parser.in_frame()") is False, 5)
        line.sendall(b"\r\x03\x03repl\r")
        assert mpy.next_line(10) == "BREAK"


def _reply(line: socket.socket, seq: int) -> Frame:
    """The board's reply (a SOF frame) with ``seq``; SIFs and the rest passed over."""
    dec = FrameDecoder()
    while True:
        data = line.recv(4096)
        if not data:
            raise ConnectionError("the board closed the link")
        for f in dec.feed(data):
            if f.kind is FrameKind.SOF and f.seq == seq:
                return f
