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

import os
import socket
import struct
import threading
import time
import tty
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from missing_link.host.board import Board
from missing_link.j2a import SOF, Frame, FrameDecoder, FrameKind, encode_frame
from missing_link.transport import open_transport
from missing_link.virtual import make_sim

from .helpers import AvrSim, FirmwareSim, wait_for

ROOT = Path(__file__).resolve().parent.parent
RIG = ROOT / "examples" / "boards" / "thesis-rig.py"
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


# ---- the CPython virtual board ----------------------------------------------------------------


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
