"""What an adversarial review of the safety paths found on the boards, fixed on every runtime it
concerns: our runtime on CPython (the ``thesis`` sim, on a board clock the test turns), the
MicroPython firmware under real MicroPython (node) and the AVR firmware in simavr.

* Only an actuator's command or a2jGoodbye can be timed (a2jAt): a timed a2jGetMapping, a2jAt
  or a2jMany crashed or reset the AVR (a 16-byte reply buffer, a call through address 0), and
  a2jAt(a2jAt(servo)) went round the daemon's allow-list.  Refused when asked, same text.
* A timed call its function refuses when due is counted as refused, not done, and said.
* An error frame heard back (RS-485 hearing itself, a tty in ECHO mode) is dropped, unanswered,
  counted; a reply of 0 heard back (an a2jGetMapping with a payload) is refused: neither keeps
  the failsafe alive by echoing for ever.
* The tail of a frame dropped after 10 ms of silence is no REPL break; a break after the quiet
  still is.
* (A stream of cut frames no longer keeps the AVR's main loop from its failsafe:
  tests/test_board_safety.py.)
"""

from __future__ import annotations

import struct

import pytest

from missing_link.j2a import SOF, encode_frame
from missing_link.testing import RuntimeBoard, call_runtime, replies
from missing_link.testing.pytest_plugin import runtime_params

from .thesis_rig import (
    H0,
    SET,
    at,
    drain,
    driver,
    inside,
    reply_on,
    run_inside,
    servo_us,
    timed_map,
)

NOT_TIMEABLE = b"only an actuator's call or a2jGoodbye can be timed"  # (every runtime's text)
#: what a2jAt must refuse (with the payload each takes): readers, a2jAt, a2jMany, the map
NOT_TIMED = [
    ("a2jGetMapping", b""),
    ("a2jAt", b"\0"),
    ("a2jMany", b""),
    ("a2jEcho", b"x"),
    ("a2jDebug", b""),
    ("a2jHostMap", b""),
    ("a2jAlignInfo", b""),
]


def test_only_actuator_calls_and_goodbye_can_be_timed(thesis: RuntimeBoard) -> None:
    """(before: a timed a2jGetMapping or a2jAt overran a 16-byte buffer on the AVR's stack and
    the CPU stopped; a timed a2jMany called address 0: a reset that made nothing safe; on the
    Python runtimes they were taken, and run when due)"""
    board = thesis.host()
    epoch = board.properties["clock.epoch"]
    board.configure({"servo.safe": "limp"})
    timed_map(board)
    for name, inner in NOT_TIMED:
        r = board.call("a2jAt", at(board.index, name, H0 + 200_000_000, inner), 5.0)
        assert (r.code, r.payload) == (0xFF, NOT_TIMEABLE), name
    assert board.call("a2jEcho", b"up", 5.0).payload == b"up"
    refused = inside(thesis, "(rt.timing.refused, rt.timing.pending())")
    assert refused in ((len(NOT_TIMED), 0), None)
    # an actuator's command and, later, a goodbye (a host that means to stop at a time)
    timed_map(board)
    board.call_ok("a2jAt", at(board.index, "a2j_set_servo", H0 + 200_000_000, b"\xc4"))
    board.call_ok("a2jAt", at(board.index, "a2jGoodbye", H0 + 600_000_000))
    seen: list[float] = []  # the servo's pulse, a turn

    def look() -> None:  # (the host talking: its failsafe quiet)
        thesis.call("a2jEcho")
        seen.append(servo_us(thesis))

    moved_then_limp = thesis.run_until(lambda: any(seen) and seen[-1] == 0, 10_000_000, look)
    assert moved_then_limp, seen  # the timed command, then the timed goodbye
    assert struct.unpack_from("<BIIII", board.call_ok("a2jAlignInfo"))[3] == 2  # both done
    if thesis.runtime != "avr":
        assert inside(thesis, "rt.failsafe.trips") == 1
    if thesis.runtime == "cpython":
        assert driver(thesis, "servo").commands == 1
    thesis.hang_up()
    again = thesis.host(describe=False)
    assert again.properties["clock.epoch"] == epoch, "the board reset"


def test_a_timed_call_refused_when_due_is_counted_and_said(thesis: RuntimeBoard) -> None:
    board = thesis.host()
    lines: list[str] = []
    board.on_log(lambda line: lines.append(line.text))
    timed_map(board)
    board.call_ok("a2jAt", at(board.index, "a2j_set_servo", H0 + 400_000_000, b"\xc4"))
    board.configure({"servo.enabled": False})  # disabled meanwhile
    thesis.run(800_000, each=lambda: thesis.call("a2jEcho"))
    if thesis.runtime != "avr":
        assert inside(thesis, "rt.timing.pending()") == 0
    done, refused = struct.unpack_from("<BIIII", board.call_ok("a2jAlignInfo"))[3:5]
    assert (done, refused) == (0, 1) and servo_us(thesis) == 0  # (before: done 1)
    if thesis.runtime == "cpython":
        assert driver(thesis, "servo").commands == 0
    said = "a timed call refused when due: a2j_set_servo"
    assert thesis.run_until(lambda: any(said in t for t in lines), 5_000_000), lines


@pytest.mark.parametrize("seed", ["error", "zero"], ids=["F0 heard back", "a reply of 0"])
def test_its_own_frames_heard_back_do_not_keep_the_failsafe_alive(
    thesis: RuntimeBoard, seed: str
) -> None:
    """The line gives the board back all it sends.  Seeded by one bad request (its F0 reply)
    or by the host's last command itself (its reply of 0 read back as an a2jGetMapping)."""
    board = thesis.host()
    board.configure({"servo.safe": "limp"})
    servo = board.index["a2j_set_servo"]
    thesis.hang_up()
    echoed: list[int] = []  # the board's replies the line gave back, a turn
    line = thesis.line()

    def loop_back() -> None:
        back = drain(line)
        echoed.append(len(replies(back)))
        line.write(back)

    try:
        line.write(encode_frame(SOF, 1, servo, struct.pack("<b", SET)))  # its reply: 0
        if seed == "error":
            line.write(encode_frame(SOF, 2, 0xF0, b""))
        thesis.run(3_000_000, each=loop_back)  # 3 s, 6 x failsafe_ms
    finally:
        line.close()
    assert any(echoed) and servo_us(thesis) == 0, "the echo kept the failsafe alive"
    if thesis.runtime != "avr":
        assert inside(thesis, "rt.failsafe.trips") == 1
    if thesis.runtime == "cpython":  # the echo died out at once (before: every turn, for ever)
        assert max(i for i, n in enumerate(echoed) if n) < 10, echoed
        assert thesis.rt.log.count(0xFF, 13) >= 1  # type: ignore[attr-defined]  # ECHOED


#: a frame's head (an a2jEcho, index 4, of 10 bytes), 10 ms of silence (the board drops it: an
#: F2), then its rest, which spells the break, and an a2jEcho: all at once, in the board's time
REST = b"\x03\x03repl\r\x00" + encode_frame(SOF, 6, 4, b"on")
DROPPED_THEN_REST = f"""
rt.take_output()
rt.feed(bytes([0x12, 5, 4, 10]))
wait_us(10001)
rt.poll()
rt.feed({REST!r})
result = (rt.breaks, rt.take_output())
"""


@pytest.mark.parametrize("board_runtime", runtime_params("cpython", "micropython"))
def test_a_frame_dropped_after_silence_leaves_no_break_behind(thesis: RuntimeBoard) -> None:
    """A frame cut by 10 ms of silence whose rest spells the REPL break is no break: its rest
    is skipped until the line is quiet again (wire.py), which the board's own time says: run
    in the runtime, as no link could keep to 10 ms on a busy machine.  A break after the quiet
    still is: what `flash` does on a port whose last owner left a frame half sent."""
    breaks, out = run_inside(thesis, DROPPED_THEN_REST)
    assert breaks == 0  # (before: 1, the firmware stopped)
    assert [(f.seq, f.opcode) for f in replies(out)][:1] == [(5, 0xF2)]  # dropped (an F2)
    assert [f.payload for f in replies(out, 6)] == [b"on"]  # ... and the next frame answered
    line = thesis.line()
    try:
        line.write(bytes([SOF, 7, 4, 9]))  # a frame's head again, then silence
        assert reply_on(thesis, line, 7).opcode == 0xF2  # dropped
        thesis.run_until(lambda: not inside(thesis, "rt.parser.in_frame()"), 1_000_000)
        line.write(b"\r\x03\x03repl\r")
        if thesis.runtime == "micropython":
            assert thesis.next_line(10) == "BREAK"  # type: ignore[attr-defined]
        assert inside(thesis, "rt.breaks") == 1
    finally:
        line.close()


@pytest.mark.parametrize("board_runtime", ["cpython"])
def test_virtual_a_timed_goodbye_drops_the_timed_calls_after_it(thesis: RuntimeBoard) -> None:
    """A timed a2jGoodbye empties the queue as it runs: what was due after it never runs
    (the loop that ran the queue once held on to the list the goodbye had replaced)."""
    rt = thesis.rt  # type: ignore[attr-defined]
    call_runtime(rt, "a2jHostMap", struct.pack("<Qqi", thesis.board_us(), H0, 0))
    assert call_runtime(rt, "a2jAt", at(rt.index, "a2jGoodbye", H0 + 100_000_000))[0] == 0
    late = at(rt.index, "a2j_set_servo", H0 + 100_000_001, b"\x40")
    assert call_runtime(rt, "a2jAt", late)[0] == 0
    thesis.turn()
    thesis.clock.advance(200_000)  # type: ignore[attr-defined]  # both due in one turn
    rt.poll()
    assert driver(thesis, "servo").commands == 0 and rt.timing.cancelled == 1
