"""What an adversarial review of the safety paths found on the boards, fixed on every runtime it
concerns: the CPython virtual board (its runtime on a clock we turn), the MicroPython firmware
under real MicroPython (node) and the AVR firmware in simavr.

* Only an actuator's command or a2jGoodbye can be timed (a2jAt): a timed a2jGetMapping, a2jAt
  or a2jMany crashed or reset the AVR (a 16-byte reply buffer, a call through address 0), and
  a2jAt(a2jAt(servo)) went round the daemon's allow-list.  Refused when asked, same text.
* A timed call its function refuses when due is counted as refused, not done, and said.
* A stream of cut frames (12 00 12 00 ...) no longer keeps the AVR's main loop from its
  failsafe.
* An error frame heard back (RS-485 hearing itself, a tty in ECHO mode) is dropped, unanswered,
  counted; a reply of 0 heard back (an a2jGetMapping with a payload) is refused: neither keeps
  the failsafe alive by echoing for ever.
* (MicroPython) the tail of a frame dropped after 10 ms of silence is no REPL break.
"""

from __future__ import annotations

import struct
import time
from collections.abc import Callable

import pytest

from missing_link.host.board import Board
from missing_link.j2a import SOF, FrameDecoder, encode_frame
from missing_link.virtual import make_sim

H0 = 1_795_000_000_000_000_000
SET = -60
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


def _at(index: dict[str, int], name: str, host_ns: int, payload: bytes = b"") -> bytes:
    return struct.pack("<qB", host_ns, index[name]) + payload


# ---- the CPython virtual board -------------------------------------------------------------------


class Clock:
    def __init__(self) -> None:
        self.us = 1_000_000

    def __call__(self) -> int:
        return self.us


def _call(rt: object, name: str, payload: bytes = b"") -> tuple[int, bytes]:
    rt.feed(encode_frame(SOF, 7, rt.index[name], payload))  # type: ignore[attr-defined]
    (frame,) = FrameDecoder().feed(rt.take_frames()[0])  # type: ignore[attr-defined]
    return frame.opcode, frame.payload


def _virtual() -> tuple[object, object, Clock]:
    clock = Clock()
    rt = make_sim("thesis", 3, clock=clock)
    servo = next(t for t in rt.transducers if t.name == "servo").driver
    limp = next(k for k in rt.config.keys if k.name == "servo.safe")
    rt.config.apply([(limp, "limp")])
    return rt, servo, clock


def _turn(rt: object, clock: Clock, us: int, host: bool = True) -> None:
    """``us`` of board time in 20 ms turns; ``host``: a frame from the host each turn."""
    for _ in range(us // 20_000):
        clock.us += 20_000
        if host:
            _call(rt, "a2jEcho")
        rt.poll()  # type: ignore[attr-defined]


def test_virtual_only_actuator_calls_and_goodbye_can_be_timed() -> None:
    rt, servo, clock = _virtual()
    index = rt.index  # type: ignore[attr-defined]
    assert _call(rt, "a2jHostMap", struct.pack("<Qqi", clock.us, H0, 0))[0] == 0
    for name, inner in NOT_TIMED:  # (before: taken, and run when due)
        assert _call(rt, "a2jAt", _at(index, name, H0 + 100_000_000, inner)) == (
            0xFF,
            NOT_TIMEABLE,
        ), name
    assert rt.timing.refused == len(NOT_TIMED) and rt.timing.pending() == 0  # type: ignore[attr-defined]
    # an actuator's command and, later, a goodbye (a host that means to stop at a time)
    fn_ok = _call(rt, "a2jAt", _at(index, "a2j_set_servo", H0 + 100_000_000, b"\xc4"))
    assert fn_ok[0] == 0
    assert _call(rt, "a2jAt", _at(index, "a2jGoodbye", H0 + 300_000_000))[0] == 0
    _turn(rt, clock, 200_000)
    assert servo.commands == 1 and not servo.limp  # type: ignore[attr-defined]
    _turn(rt, clock, 200_000)
    assert servo.limp and rt.failsafe.trips == 1  # type: ignore[attr-defined]
    assert rt.timing.done == 2  # type: ignore[attr-defined]


def test_virtual_a_timed_goodbye_drops_the_timed_calls_after_it() -> None:
    """A timed a2jGoodbye empties the queue as it runs: what was due after it never runs
    (the loop that ran the queue once held on to the list the goodbye had replaced)."""
    rt, servo, clock = _virtual()
    index = rt.index  # type: ignore[attr-defined]
    _call(rt, "a2jHostMap", struct.pack("<Qqi", clock.us, H0, 0))
    assert _call(rt, "a2jAt", _at(index, "a2jGoodbye", H0 + 100_000_000))[0] == 0
    late = _at(index, "a2j_set_servo", H0 + 100_000_001, b"\x40")
    assert _call(rt, "a2jAt", late)[0] == 0
    _turn(rt, clock, 20_000)
    rt.take_frames()  # type: ignore[attr-defined]
    clock.us += 200_000  # both due in one turn
    rt.poll()  # type: ignore[attr-defined]
    assert servo.commands == 0 and rt.timing.cancelled == 1  # type: ignore[attr-defined]


def test_virtual_a_timed_call_refused_when_due_is_counted_and_said() -> None:
    rt, servo, clock = _virtual()
    index = rt.index  # type: ignore[attr-defined]
    _call(rt, "a2jHostMap", struct.pack("<Qqi", clock.us, H0, 0))
    assert _call(rt, "a2jAt", _at(index, "a2j_set_servo", H0 + 100_000_000, b"\xc4"))[0] == 0
    off = next(k for k in rt.config.keys if k.name == "servo.enabled")  # type: ignore[attr-defined]
    rt.config.apply([(off, False)])  # type: ignore[attr-defined]  # disabled meanwhile
    rt.take_frames()  # type: ignore[attr-defined]
    _turn(rt, clock, 200_000, host=False)  # (within failsafe_ms)
    sifs = FrameDecoder().feed(b"".join(rt.take_frames()[1]))  # type: ignore[attr-defined]
    done, refused = struct.unpack("<BIIII", _call(rt, "a2jAlignInfo")[1])[3:5]
    assert servo.commands == 0 and (done, refused) == (0, 1)  # (before: done 1, refused 0)
    said = b"".join(f.payload for f in sifs if f.opcode == 0xFE)
    assert b"a timed call refused when due: a2j_set_servo" in said


@pytest.mark.parametrize("seed", ["error", "zero"], ids=["F0 heard back", "a reply of 0"])
def test_virtual_its_own_frames_heard_back_do_not_keep_the_failsafe_alive(seed: str) -> None:
    """The line gives the board back all it sends.  Seeded by one bad request (its F0 reply)
    or by the host's last command itself (its reply of 0 read back as an a2jGetMapping)."""
    rt, servo, clock = _virtual()
    rt.feed(encode_frame(SOF, 1, rt.index["a2j_set_servo"], struct.pack("<b", SET)))  # type: ignore[attr-defined]
    if seed == "error":
        rt.take_frames()  # type: ignore[attr-defined]
        rt.feed(encode_frame(SOF, 2, 0xF0, b""))  # type: ignore[attr-defined]
    last = 0  # the last turn the board answered something
    for turn in range(150):  # 3 s; the line gives the board back what it sent
        replies, sifs = rt.take_frames()  # type: ignore[attr-defined]
        last = turn if replies else last
        rt.feed(replies + b"".join(sifs))  # type: ignore[attr-defined]
        clock.us += 20_000
        rt.poll()  # type: ignore[attr-defined]
    assert rt.failsafe.trips == 1 and servo.limp  # type: ignore[attr-defined]
    assert last < 10  # the echo died out at once (before: a reply every turn, for ever)
    assert rt.log.count(0xFF, 13) >= 1  # type: ignore[attr-defined]  # counted: ECHOED


def test_virtual_damaged_frames_are_no_sign_of_a_host() -> None:
    """Cut, bad-checksum and bad-escape frames every turn (each answered with its error frame)
    do not count as the host: the failsafe trips as on a silent line."""
    rt, servo, clock = _virtual()
    rt.feed(encode_frame(SOF, 1, rt.index["a2j_set_servo"], struct.pack("<b", SET)))  # type: ignore[attr-defined]
    good = encode_frame(SOF, 2, rt.index["a2jEcho"], b"x")  # type: ignore[attr-defined]
    bad_sum = good[:-1] + bytes([good[-1] ^ 0xFF])
    for _ in range(150):  # 3 s, a burst of damage every 20 ms
        rt.feed(bytes.fromhex("1200") * 64 + bad_sum + b"\x12\x03\x04\x01\xed\x00")  # type: ignore[attr-defined]
        rt.take_frames()  # type: ignore[attr-defined]
        clock.us += 20_000
        rt.poll()  # type: ignore[attr-defined]
    assert rt.failsafe.trips == 1 and servo.limp  # type: ignore[attr-defined]
    assert rt.parser.errors > 150 * 64  # type: ignore[attr-defined]  # (all of it was damage)


def test_virtual_a_frame_dropped_after_silence_leaves_no_break_behind() -> None:
    """A frame cut by 10 ms of silence whose rest spells the REPL break is no break: its rest
    is skipped until the line is quiet again (wire.py).  A break after the quiet still is."""
    rt, _servo, clock = _virtual()
    tail = b"\x03\x03repl\r"
    rt.feed(bytes([SOF, 5, rt.index["a2jEcho"], len(tail) + 1]))  # type: ignore[attr-defined]
    clock.us += 10_001
    rt.poll()  # type: ignore[attr-defined]  # the frame is dropped (an F2) ...
    rt.feed(tail + b"\x00")  # type: ignore[attr-defined]  # ... and then its rest comes
    assert rt.breaks == 0  # type: ignore[attr-defined]  # (before: 1, the firmware stopped)
    clock.us += 10_001
    rt.poll()  # type: ignore[attr-defined]
    rt.feed(tail)  # type: ignore[attr-defined]
    assert rt.breaks == 1  # type: ignore[attr-defined]


# ---- through the host, on the firmware (test_safety_review_mpy.py, _avr.py) ----------------------
def _timed_map(board: Board) -> int:
    """Hand the board a map whose H0 is its time now; returns that board time."""
    now = board.clock_exchange(5.0).t3
    board.call_ok("a2jHostMap", struct.pack("<Qqi", now, H0, 0))
    return now


def _refuses_what_is_not_timeable(board: Board) -> None:
    _timed_map(board)
    for name, inner in NOT_TIMED:
        r = board.call("a2jAt", _at(board.index, name, H0 + 200_000_000, inner), 5.0)
        assert (r.code, r.payload) == (0xFF, NOT_TIMEABLE), name
    assert board.call("a2jEcho", b"up", 5.0).payload == b"up"


def _keep_talking(board: Board, s: float) -> None:
    end = time.monotonic() + s
    while time.monotonic() < end:
        board.call("a2jEcho", b"", 5.0)
        time.sleep(0.05)


def _moves_then_goes_limp(board: Board, pulse: Callable[[], float]) -> bool:
    """Talking to the board (its failsafe quiet) until its servo pulsed and then went limp:
    the timed command, then the timed goodbye (within 10 s: a bound on a hang)."""
    moved = False
    end = time.monotonic() + 10
    while time.monotonic() < end:
        board.call("a2jEcho", b"", 5.0)
        if pulse() != 0:
            moved = True
        elif moved:
            return True
        time.sleep(0.05)
    return False
