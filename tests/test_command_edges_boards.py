"""Values at and beyond the edges of an actuator's type, sent raw to the board (issue 43.1), on
every runtime: the mega rover's board file (two H-bridges, a stepper, a servo) as the CPython
virtual board, as the MicroPython firmware under node and as the AVR firmware in simavr.  The
host refuses such values before they are packed (tests/test_command_edges.py); a board takes
bytes from anyone on its link, so each runtime refuses the same ones itself, the same way, and
stays up with its actuators where they were.

Before, the AVR stepper took +inf and 3.4e38 rev as a position (``lroundf`` of them is
undefined, the goal in steps overflowed its int32) where the Python runtimes said "too far"."""

from __future__ import annotations

import struct
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from missing_link.host.board import Board
from missing_link.transport import open_transport

from .helpers import AvrRig, FirmwareSim, board_process

ROOT = Path(__file__).resolve().parent.parent
MEGA = ROOT / "examples" / "boards" / "rover-mega.py"
OK, NO = 0, 0xFF
F32_MAX = struct.unpack("<f", b"\xff\xff\x7f\x7f")[0]


def f32(bits: int) -> bytes:
    return struct.pack("<I", bits)


def f(value: float) -> bytes:
    return struct.pack("<f", value)


NAN, QNAN_NEG, INF, NINF = f32(0x7FC00000), f32(0xFFC00001), f32(0x7F800000), f32(0xFF800000)
DENORMAL, NEG_ZERO = f32(0x00000001), f32(0x80000000)

#: (function, payload, what the board answers): the same on every runtime
EDGES = [
    # the H-bridge's duty: -1..1, nothing else (NaN and the infinities are no duty)
    ("a2j_motor_l", NAN, NO),
    ("a2j_motor_l", QNAN_NEG, NO),
    ("a2j_motor_l", INF, NO),
    ("a2j_motor_l", NINF, NO),
    ("a2j_motor_l", f(F32_MAX), NO),
    ("a2j_motor_l", f(-F32_MAX), NO),
    ("a2j_motor_l", f(1.0000001), NO),
    ("a2j_motor_l", b"\x00\x00\x80", NO),  # 3 bytes
    ("a2j_motor_l", f(0.0) + b"\x00", NO),  # 5 bytes
    ("a2j_motor_l", DENORMAL, OK),
    ("a2j_motor_l", NEG_ZERO, OK),
    ("a2j_motor_l", f(-1.0), OK),
    ("a2j_motor_l", f(0.0), OK),
    # the stepper's position in rev: NaN lets go; beyond 1e6 rev (or its steps beyond an
    # int32) is too far, the infinities too
    ("a2j_mast", INF, NO),
    ("a2j_mast", NINF, NO),
    ("a2j_mast", f(F32_MAX), NO),
    ("a2j_mast", f(-F32_MAX), NO),
    ("a2j_mast", f(1000001.0), NO),
    ("a2j_mast", f(2.0e9), NO),
    ("a2j_mast", b"", NO),
    ("a2j_mast", DENORMAL, OK),
    ("a2j_mast", NEG_ZERO, OK),
    ("a2j_mast", NAN, OK),  # (N/A: let go)
    # the servo: an int8, -128 its N/A
    ("a2j_set_servo", b"\x80", NO),
    ("a2j_set_servo", b"\x7f\x00", NO),
    ("a2j_set_servo", b"\x7f", OK),
    ("a2j_set_servo", b"\x81", OK),
    ("a2j_set_servo", b"\x00", OK),
]


def answers(board: Board) -> list[tuple[str, str, int]]:
    return [(fn, p.hex(), board.call(fn, p).code) for fn, p, _want in EDGES]


def check(url: str) -> None:
    board = Board(open_transport(url), timeout=5.0)
    try:
        board.handshake()
        epoch = board.properties.get("clock.epoch")
        got = answers(board)
        want = [(fn, p.hex(), code) for fn, p, code in EDGES]
        assert got == want, [g for g, w in zip(got, want, strict=True) if g != w]
        assert board.call("a2jEcho", b"up").payload == b"up"  # (up, the same boot)
        board.handshake(describe=False)
        assert board.properties.get("clock.epoch") == epoch, "the board reset"
        board.call_ok("a2jGoodbye")
    finally:
        board.close()


@contextmanager
def _mpy() -> Iterator[str]:
    sim = FirmwareSim(MEGA)
    try:
        yield sim.url
    finally:
        sim.close()


@pytest.mark.slow
def test_cpython_board_refuses_edge_values_alike() -> None:
    with board_process("--file", str(MEGA)) as url:
        check(url)


@pytest.mark.slow
@pytest.mark.micropython
def test_micropython_board_refuses_edge_values_alike() -> None:
    with _mpy() as url:
        check(url)


@pytest.mark.slow
@pytest.mark.avr
def test_avr_board_refuses_edge_values_alike(avr_rig: AvrRig) -> None:
    rig = avr_rig("mega_rover", rover=True)
    check(rig.url)
    assert rig.proc.poll() is None


_: Callable[..., object] = check  # (the table is the test: one body for every runtime)
