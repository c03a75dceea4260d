"""The firmware survives the host's mistakes (issue 34.7), on every runtime (the thesis fixture:
our runtime on CPython, the MicroPython firmware, the AVR firmware): a bad host map is refused
and nothing stops; line noise does not stop the firmware and the break makes it safe; a crash
makes the actuators safe first (the timed commands and the failsafe: tests/test_board_safety.py)."""

from __future__ import annotations

import struct

import pytest

from missing_link.host.board import Board
from missing_link.testing import FakeBoardClock, RuntimeBoard, wait_for
from missing_link.testing.pytest_plugin import runtime_params
from missing_link.transport import open_transport
from missing_link.virtual import make_sim, start_board_thread

from .thesis_rig import H0, SET, inside, servo_us


def _bad_maps(b0: int) -> list[tuple[bytes, str]]:
    """(payload, what the board says) of maps a host got wrong, around board µs ``b0``."""
    beyond = "board us beyond 2^63 or host ns beyond +-2^62"
    return [
        (struct.pack("<Qqi", b0, H0, -1_000_000_000), "rate off by more than 10 % (ppb)"),
        (struct.pack("<Qqi", b0, H0, 100_000_001), "rate off by more than 10 % (ppb)"),
        (struct.pack("<Qqi", b0, H0, -100_000_001), "rate off by more than 10 % (ppb)"),
        (struct.pack("<Qqi", 1 << 63, H0, 0), beyond),
        (struct.pack("<Qqi", b0, -(1 << 62) - 1, 0), beyond),
        (struct.pack("<Qqi", b0, (1 << 62) + 1, 0), beyond),
        (b"\x00" * 19, "expects <Q board us><q host ns><i ppb> or nothing"),
    ]


def test_a_bad_host_map_is_refused_and_nothing_stops(thesis: RuntimeBoard) -> None:
    """(the firmware survives the host's mistakes, issue 34.7) A rate of -1e9 ppb divided by
    zero in the aligned ranger's next sample (a ZeroDivisionError out of poll: the board's loop
    stopped).  Each bad map is refused, saying why; the good one before it is kept."""
    board = thesis.host()
    board.configure({"dist_ir.aligned": True})
    b0 = board.clock_exchange(5.0).t3
    good = struct.pack("<Qqi", b0, H0, 40_000)
    assert thesis.call("a2jHostMap", good) == (0, b"")
    for payload, said in _bad_maps(b0):
        code, text = thesis.call("a2jHostMap", payload)
        assert (code, text.decode()) == (0xFF, said), payload.hex()
    assert thesis.call("a2jHostMap", b"") == (0, good)
    sent = inside(thesis, "rt.sifs_sent")  # the aligned ranger asks the map for its grid
    if sent is not None:  # and its samples go on
        more = thesis.run_until(
            lambda: inside(thesis, "rt.sifs_sent") >= sent + 10,
            5_000_000,
            each=lambda: thesis.call("a2jEcho"),
        )
        assert more
    assert thesis.call("a2jEcho", b"up").payload == b"up"


@pytest.mark.parametrize("board_runtime", runtime_params("micropython"))
def test_line_noise_does_not_stop_the_firmware_and_the_break_makes_it_safe(
    thesis: RuntimeBoard,
) -> None:
    """Two 0x03 between frames stopped the firmware with its actuators going on (aa 03 03 did
    it).  Now neither that, nor mpremote's own Ctrl-C, nor a near miss stops it; the break
    (Ctrl-C twice, "repl", Enter) does, with every armed actuator made safe first.  (Its
    failsafe a minute: the silence meanwhile, however slow the machine, trips nothing.)"""
    board = thesis.host()
    board.configure({"servo.safe": "limp", "servo.failsafe_ms": 60000})
    board.call_ok("a2j_set_servo", struct.pack("<b", SET))
    thesis.hang_up()
    line = thesis.line()
    try:
        for noise in (b"\xaa\x03\x03", b"\r\x03\x03", b"\r\x03\r\x01", b"\x03\x03rep\r\x03\x03"):
            junk = inside(thesis, "rt.parser.junk") + len(noise)
            line.write(noise)  # (taken as junk between frames, once the firmware has read it)
            assert wait_for(lambda j=junk: inside(thesis, "rt.parser.junk") >= j, 5)
        assert inside(thesis, "(rt.breaks, rt.failsafe.trips)") == (0, 0)
        assert servo_us(thesis) == 1217
        line.write(b"\x03\x03repl\r")
        assert thesis.next_line(10) == "BREAK"  # type: ignore[attr-defined]
    finally:
        line.close()
    assert servo_us(thesis) == 0  # limp: made safe before the firmware stopped
    debug = inside(thesis, "bytes(rt._debug)").decode()
    assert "failsafe: servo safe (the firmware stops: the break to the REPL);" in debug


@pytest.mark.parametrize("board_runtime", runtime_params("micropython"))
def test_a_crash_makes_the_actuators_safe_first(thesis: RuntimeBoard) -> None:
    board = thesis.host()
    board.configure({"servo.safe": "limp"})
    board.call_ok("a2j_set_servo", struct.pack("<b", SET))
    thesis.hang_up()
    thesis.ctl(  # type: ignore[attr-defined]  # a driver that raises, as a bug would
        "def boom(now, fresh=False):\n    raise RuntimeError('driver bug')\n"
        "next(t for t in rt.transducers if t.name == 'imu')._poll = boom"
    )
    assert thesis.next_line(10) == "CRASH"  # type: ignore[attr-defined]
    assert servo_us(thesis) == 0
    assert "the firmware stops: driver bug" in inside(thesis, "bytes(rt._debug)").decode()


@pytest.mark.filterwarnings("ignore::pytest.PytestUnhandledThreadExceptionWarning")  # (its end)
def test_virtual_a_board_that_fails_makes_its_actuators_safe_first() -> None:
    """A virtual board whose loop raises stops (its thread ends, as the firmware does), with
    every armed actuator made safe first."""
    rt = make_sim("thesis", 3, clock=FakeBoardClock())
    servo = next(t for t in rt.transducers if t.name == "servo").driver
    server, thread = start_board_thread(rt, "tcp://127.0.0.1:0")
    board = Board(open_transport(server.url), timeout=5.0)
    try:
        board.handshake(describe=False)
        board.configure({"servo.safe": "limp"})
        board.call_ok("a2j_set_servo", struct.pack("<b", SET))

        def boom(now: int, fresh: bool = False) -> None:  # (a paced driver's poll: Periodic)
            raise RuntimeError("driver bug")

        rt.transducers[0]._poll = boom  # type: ignore[attr-defined]  # (as a bug would)
        thread.join(10)
        assert not thread.is_alive()
    finally:
        board.close()
        server.stop()
    assert servo.limp  # type: ignore[attr-defined]
    assert "servo safe (the firmware stops: driver bug);" in bytes(rt._debug).decode()  # type: ignore[attr-defined]
