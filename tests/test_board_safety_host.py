"""The firmware survives the host's mistakes (issue 34.7), on every runtime (the CPython virtual
board, the MicroPython firmware, the AVR firmware): a bad host map is refused and nothing stops;
line noise does not stop the firmware and the break makes it safe; a crash makes the actuators
safe first (the timed commands and the failsafe: tests/test_board_safety.py)."""

from __future__ import annotations

import socket
import struct
from collections.abc import Callable

import pytest

from missing_link.host.board import Board
from missing_link.transport import open_transport
from missing_link.virtual import start_board_thread

from .helpers import AvrSim, FirmwareSim, wait_for
from .test_board_safety import H0, SET, Clock, _call, _mpy_servo, _reaches, _run, _virtual
from .test_board_safety import mpy as mpy  # (a fixture)
from .test_board_safety import rig as rig  # (a fixture)

# ---- the firmware survives the host's mistakes (issue 34.7) -------------------------------------


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


def _refuses_bad_maps(call: Callable[[str, bytes], tuple[int, bytes]], b0: int) -> None:
    """Each bad map refused, saying why; the good one before (valid: ``b0`` is now) kept."""
    good = struct.pack("<Qqi", b0, H0, 40_000)
    assert call("a2jHostMap", good) == (0, b"")
    for payload, said in _bad_maps(b0):
        code, text = call("a2jHostMap", payload)
        assert (code, text.decode()) == (0xFF, said), payload.hex()
    assert call("a2jHostMap", b"") == (0, good)


def _caller(board: Board) -> Callable[[str, bytes], tuple[int, bytes]]:
    def call(name: str, payload: bytes) -> tuple[int, bytes]:
        r = board.call(name, payload)
        return r.code, r.payload

    return call


def test_virtual_a_bad_host_map_is_refused_and_nothing_stops() -> None:
    """A rate of -1e9 ppb divided by zero in the aligned ranger's next sample (a
    ZeroDivisionError out of poll: the board's loop stopped)."""
    clock = Clock()
    rt, _servo = _virtual(clock)
    keys = {k.name: k for k in rt.config.keys}  # type: ignore[attr-defined]
    rt.config.apply([(keys["dist_ir.aligned"], True)])  # type: ignore[attr-defined]
    _refuses_bad_maps(lambda name, payload: _call(rt, name, payload), clock.us)
    _run(rt, clock, 500_000)  # the aligned ranger asks the map for its grid
    assert _call(rt, "a2jEcho", b"up")[1] == b"up"


@pytest.mark.slow
@pytest.mark.micropython
def test_micropython_a_bad_host_map_is_refused_and_nothing_stops(mpy: FirmwareSim) -> None:
    board = Board(open_transport(mpy.url), timeout=5.0)
    try:
        board.handshake()
        board.configure({"dist_ir.aligned": True})
        _refuses_bad_maps(_caller(board), board.clock_exchange(5.0).t3)
        sent = mpy.ctl("result = rt.sifs_sent")  # the aligned ranger's samples go on
        assert wait_for(_reaches(mpy, "rt.sifs_sent", sent + 10), 5)
        assert board.call("a2jEcho", b"up").payload == b"up"
    finally:
        board.close()


@pytest.mark.slow
@pytest.mark.avr
def test_avr_a_bad_host_map_is_refused_and_nothing_stops(rig: AvrSim) -> None:
    board = Board(open_transport(rig.url), timeout=5.0)
    try:
        board.handshake()
        board.configure({"dist_ir.aligned": True})
        _refuses_bad_maps(_caller(board), board.clock_exchange(5.0).t3)
        assert board.call("a2jEcho", b"up").payload == b"up"
    finally:
        board.close()


@pytest.mark.slow
@pytest.mark.micropython
def test_micropython_line_noise_does_not_stop_the_firmware_and_the_break_makes_it_safe(
    mpy: FirmwareSim,
) -> None:
    """Two 0x03 between frames stopped the firmware with its actuators going on (aa 03 03 did
    it).  Now neither that, nor mpremote's own Ctrl-C, nor a near miss stops it; the break
    (Ctrl-C twice, "repl", Enter) does, with every armed actuator made safe first."""
    board = Board(open_transport(mpy.url), timeout=5.0)
    try:
        board.handshake()
        board.configure({"servo.safe": "limp"})
        board.call_ok("a2j_set_servo", struct.pack("<b", SET))
    finally:
        board.close()
    host, port = mpy.url[len("tcp://") :].split(":")
    with socket.create_connection((host, int(port)), timeout=5) as c:
        for noise in (b"\xaa\x03\x03", b"\r\x03\x03", b"\r\x03\r\x01", b"\x03\x03rep\r\x03\x03"):
            junk = mpy.ctl("result = rt.parser.junk")
            c.sendall(noise)  # (taken as junk between frames, once the firmware has read it)
            assert wait_for(_reaches(mpy, "rt.parser.junk", junk + len(noise)), 5)
        assert mpy.ctl("result = (rt.breaks, rt.failsafe.trips)") == (0, 0)
        assert _mpy_servo(mpy) == 1217
        c.sendall(b"\x03\x03repl\r")
        assert mpy.next_line(10) == "BREAK"
    assert _mpy_servo(mpy) == 0  # limp: made safe before the firmware stopped
    debug = mpy.ctl("result = bytes(rt._debug)").decode()
    assert "failsafe: servo safe (the firmware stops: the break to the REPL);" in debug


@pytest.mark.slow
@pytest.mark.micropython
def test_micropython_a_crash_makes_the_actuators_safe_first(mpy: FirmwareSim) -> None:
    board = Board(open_transport(mpy.url), timeout=5.0)
    try:
        board.handshake()
        board.configure({"servo.safe": "limp"})
        board.call_ok("a2j_set_servo", struct.pack("<b", SET))
    finally:
        board.close()
    mpy.ctl(  # a driver that raises, as a bug would
        "def boom(now):\n    raise RuntimeError('driver bug')\n"
        "next(t for t in rt.transducers if t.name == 'imu')._poll = boom"
    )
    assert mpy.next_line(10) == "CRASH"
    assert _mpy_servo(mpy) == 0
    assert "the firmware stops: driver bug" in mpy.ctl("result = bytes(rt._debug)").decode()


@pytest.mark.filterwarnings("ignore::pytest.PytestUnhandledThreadExceptionWarning")  # (its end)
def test_virtual_a_board_that_fails_makes_its_actuators_safe_first() -> None:
    """A virtual board whose loop raises stops (its thread ends, as the firmware does), with
    every armed actuator made safe first."""
    rt, servo = _virtual(Clock())
    server, thread = start_board_thread(rt, "tcp://127.0.0.1:0")  # type: ignore[arg-type]
    board = Board(open_transport(server.url), timeout=5.0)
    try:
        board.handshake(describe=False)
        board.configure({"servo.safe": "limp"})
        board.call_ok("a2j_set_servo", struct.pack("<b", SET))

        def boom(now: int) -> None:
            raise RuntimeError("driver bug")

        rt.transducers[0]._poll = boom  # type: ignore[attr-defined]  # (as a bug would)
        thread.join(10)
        assert not thread.is_alive()
    finally:
        board.close()
        server.stop()
    assert servo.limp  # type: ignore[attr-defined]
    assert "servo safe (the firmware stops: driver bug);" in bytes(rt._debug).decode()  # type: ignore[attr-defined]
