"""Nothing moves after the host has gone (issue 34.1), on every runtime: our runtime on CPython
(the ``thesis`` sim, on a board clock the test turns), the MicroPython firmware under real
MicroPython (node) and the AVR firmware in simavr (the ``thesis`` fixture: tests/conftest.py).
A servo is set to -60 and handed a timed command (a2jAt) for 100; then the host says goodbye,
or falls silent: the servo never moves there, on any runtime, and the board says it dropped the
call.  Damaged frames (line noise, a stream of cut frames) are no sign of a living host: a servo
commanded and then fed nothing but damage goes to its safe state after its failsafe_ms as if the
line were quiet.  (The host's mistakes, a firmware that stops: tests/test_board_safety_host.py.)"""

from __future__ import annotations

import struct
from collections.abc import Callable

import pytest

from missing_link.j2a import SOF, encode_frame
from missing_link.testing import RuntimeBoard, call_runtime

from .thesis_rig import (
    H0,
    HELD,
    SET,
    TIMED,
    damaged_frames,
    drain,
    driver,
    inside,
    peek_u32,
    servo_us,
    timed_map,
)


@pytest.mark.parametrize("goodbye", [True, False], ids=["goodbye", "silence"])
def test_a_timed_command_never_runs_after_the_host_has_gone(
    thesis: RuntimeBoard, goodbye: bool
) -> None:
    board = thesis.host()
    board.call_ok("a2j_set_servo", struct.pack("<b", SET))
    thesis.run(1_000_000, each=lambda: thesis.call("a2jEcho"))  # the horn gets there
    held = servo_us(thesis)
    assert held == HELD[thesis.runtime]
    now = timed_map(board)
    payload = struct.pack("<qB", H0 + 1_500_000_000, board.index["a2j_set_servo"])
    tick = int(struct.unpack("<Q", board.call_ok("a2jAt", payload + struct.pack("<b", TIMED)))[0])
    assert tick == now + 1_500_000
    camera = "a2j_trigger" in board.index  # (the firmware's camera: a pulse on Timer2 on AVR)
    if camera:
        edges = trigger_edges(thesis)
        pulse = struct.pack("<qB", H0 + 1_400_000_000, board.index["a2j_trigger"]) + b"\x14\0"
        board.call_ok("a2jAt", pulse)
    if goodbye:
        board.call_ok("a2jGoodbye")
    thesis.hang_up()  # the link closed: the host is gone
    thesis.run(2_500_000)  # past the tick, the host silent
    assert servo_us(thesis) == held  # (before: 1972 µs, the late command, and held there)
    dropped = 1 + camera
    if camera:
        assert trigger_edges(thesis) == edges
    if thesis.runtime == "cpython":
        servo = driver(thesis, "servo")
        assert servo.commands == 1 and servo.position == servo.target  # (before: 2)
    if thesis.runtime == "avr":
        assert peek_u32(thesis, "timing_cancelled") == dropped
    else:
        assert inside(thesis, "(rt.timing.cancelled, rt.timing.done)") == (dropped, 0)
    debug = thesis.call("a2jDebug").payload.decode()  # (a host again; 64 bytes on AVR)
    assert struct.unpack_from("<BIIII", thesis.call("a2jAlignInfo").payload)[3] == 0  # none done
    why = "the host said goodbye" if goodbye else "no frame from the host for 500 ms"
    said = f"timing: {dropped} timed call{'s' * (dropped > 1)} dropped ({why});"
    if thesis.runtime == "cpython" or goodbye:
        assert said in debug, debug


def trigger_edges(rig: RuntimeBoard) -> object:
    if rig.runtime == "avr":
        return rig.ctl("trig").split()[1]  # type: ignore[attr-defined]
    return inside(rig, "len(WORLD.edges.get(16, ()))")


def _noise(echo: int) -> bytes:
    return damaged_frames(echo)


def _cut_frames(echo: int) -> bytes:
    """12 00 12 00 ... (an F2 for every 2 bytes; main.c emptied the AVR's receive ring before
    each failsafe_poll: the stream kept it there for ever), a bad checksum, a bad escape."""
    good = encode_frame(SOF, 2, echo, b"x")
    return (
        bytes.fromhex("1200") * 256
        + good[:-1]
        + bytes([good[-1] ^ 0xFF])
        + b"\x12\x03\x04\x01\xed\x00"
    )


@pytest.mark.parametrize("damage", [_noise, _cut_frames], ids=["damaged frames", "cut frames"])
def test_damage_on_the_line_does_not_keep_the_failsafe_from_tripping(
    thesis: RuntimeBoard, damage: Callable[[int], bytes]
) -> None:
    """Cut, bad-checksum and bad-escape frames and another board's every turn (each answered
    with its error frame): the failsafe trips as on a silent line."""
    board = thesis.host()
    board.configure({"servo.safe": "limp"})
    board.call_ok("a2j_set_servo", struct.pack("<b", SET))
    noise = damage(board.index["a2jEcho"])
    thesis.hang_up()
    assert servo_us(thesis) != 0
    if thesis.runtime == "micropython":
        assert servo_us(thesis) == HELD["micropython"]
    line = thesis.line()
    try:
        errors = inside(thesis, "rt.parser.errors")
        if damage is _cut_frames:  # 2 s of board time, 4 x failsafe_ms
            thesis.run(2_000_000, each=lambda: (line.write(noise), drain(line)))
        else:  # until the servo is safe, within 3 s (it must come)
            safe = thesis.run_until(
                lambda: servo_us(thesis) == 0,
                3_000_000,
                each=lambda: (line.write(noise), drain(line)),
            )
            assert safe, "3 s of damaged frames and the failsafe has not tripped"
    finally:
        line.close()
    assert servo_us(thesis) == 0, "the failsafe has not tripped"  # limp: no pulse
    if thesis.runtime != "avr":
        assert inside(thesis, "rt.failsafe.trips") == 1
    if thesis.runtime == "cpython" and damage is _cut_frames:
        assert inside(thesis, "rt.parser.errors") - errors > 150 * 64  # (all of it damage)


@pytest.mark.parametrize("board_runtime", ["cpython"])
def test_virtual_hold_keeps_the_last_command_as_the_firmware_does(thesis: RuntimeBoard) -> None:
    """The virtual servo made safe with `hold` goes on to its last command (the firmware keeps
    its last pulse); it no longer stops where it happened to be, which hid a late command."""
    rt = thesis.rt  # type: ignore[attr-defined]
    call_runtime(rt, "a2j_set_servo", struct.pack("<b", 127))
    thesis.turn()
    call_runtime(rt, "a2jGoodbye")  # half-way there
    thesis.run(1_000_000)
    servo = driver(thesis, "servo")
    assert servo.position == servo.target == 90
