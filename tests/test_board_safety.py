"""Nothing moves after the host has gone (issue 34.1), on every runtime: the CPython virtual
board (its runtime with a clock we turn), the MicroPython firmware under real MicroPython (node)
and the AVR firmware in simavr.  A servo is set to -60 and handed a timed command (a2jAt) for
100; then the host says goodbye, or falls silent: the servo never moves there, on any runtime,
and the board says it dropped the call.  And damaged frames (line noise) are no sign of a living
host: a servo commanded and then fed nothing but damaged frames goes to its safe state after its
failsafe_ms as if the line were quiet."""

from __future__ import annotations

import socket
import struct
import subprocess
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from missing_link.host.board import Board
from missing_link.j2a import SOF, SOS, FrameDecoder, encode_frame
from missing_link.transport import open_transport
from missing_link.virtual import make_sim

from .helpers import AvrSim, FirmwareSim, wait_for

ROOT = Path(__file__).resolve().parent.parent
RIG = ROOT / "examples" / "boards" / "thesis-rig.py"
H0 = 1_795_000_000_000_000_000  # host ns of the pushed map's reference (any epoch)
SET, TIMED = -60, 100  # the servo's command now, and the one for later


def damaged_frames(echo: int) -> bytes:
    """One of each kind of damage, addressed to the board (an a2jEcho: were one taken as intact
    by mistake, still nothing moves), and an intact frame from another board (SOS), which a
    board ignores: none of them is a frame from the host."""
    good = encode_frame(SOF, 9, echo, b"\x01\x02")
    assert good[-1] ^ 0x01 not in (0x12, 0xED, 0x7D) and good[-2] != 0x7D
    bad_checksum = good[:-1] + bytes([good[-1] ^ 0x01])
    cut = good[:4]  # cut by the next frame's start
    bad_escape = bytes([SOF, 9, 0x7D, 0x00])  # 7D 00 escapes to 0x01: not a special byte
    return bad_checksum + cut + bad_escape + encode_frame(SOS, 1, 0, b"\x05") + bytes([0x55, 0xAA])


def _timed(board: Board, name: str, value: int, ahead_us: int) -> int:
    """Hand the board a map of its clock and a timed call of ``name`` with ``value`` that far
    ahead; the tick it will act at."""
    now = board.clock_exchange(5.0).t3
    board.call_ok("a2jHostMap", struct.pack("<Qqi", now, H0, 0))
    at = H0 + ahead_us * 1000
    payload = struct.pack("<qB", at, board.index[name]) + struct.pack("<b", value)
    tick = int(struct.unpack("<Q", board.call_ok("a2jAt", payload))[0])
    assert tick == now + ahead_us
    return tick


# ---- the CPython virtual board -------------------------------------------------------------------


class Clock:
    def __init__(self) -> None:
        self.us = 1_000_000

    def __call__(self) -> int:
        return self.us


def _call(rt: object, name: str, payload: bytes = b"") -> tuple[int, bytes]:
    rt.feed(encode_frame(SOF, 7, rt.index[name], payload))  # type: ignore[attr-defined]
    replies = rt.take_frames()[0]  # type: ignore[attr-defined]
    (frame,) = FrameDecoder().feed(replies)
    return frame.opcode, frame.payload


def _virtual(clock: Clock) -> tuple[object, object]:
    rt = make_sim("thesis", 3, clock=clock)
    servo = next(t for t in rt.transducers if t.name == "servo").driver
    return rt, servo


def _run(rt: object, clock: Clock, us: int) -> None:
    for _ in range(us // 20_000):
        clock.us += 20_000
        rt.poll()  # type: ignore[attr-defined]


def _virtual_timed(rt: object, clock: Clock, ahead_us: int) -> int:
    _call(rt, "a2jHostMap", struct.pack("<Qqi", clock.us, H0, 0))
    fn = rt.index["a2j_set_servo"]  # type: ignore[attr-defined]
    code, reply = _call(rt, "a2jAt", struct.pack("<qBb", H0 + ahead_us * 1000, fn, TIMED))
    assert code == 0
    return int(struct.unpack("<Q", reply)[0])


@pytest.mark.parametrize("goodbye", [True, False], ids=["goodbye", "silence"])
def test_virtual_a_timed_command_never_runs_after_the_host_has_gone(goodbye: bool) -> None:
    clock = Clock()
    rt, servo = _virtual(clock)
    assert _call(rt, "a2j_set_servo", struct.pack("<b", SET))[0] == 0
    _run(rt, clock, 1_000_000)  # the horn gets there (the host quiet: within failsafe_ms)
    _call(rt, "a2jEcho")
    held = servo.position  # type: ignore[attr-defined]
    assert held == pytest.approx(SET * 90 / 127)
    tick = _virtual_timed(rt, clock, 1_500_000)
    if goodbye:
        assert _call(rt, "a2jGoodbye") == (0, b"")
    _run(rt, clock, tick - clock.us + 1_000_000)  # past the tick, the host silent
    assert servo.commands == 1  # type: ignore[attr-defined]  # (before: 2, the late one too)
    assert servo.position == held and servo.target == held  # type: ignore[attr-defined]
    assert rt.timing.done == 0 and rt.timing.cancelled == 1  # type: ignore[attr-defined]
    why = "the host said goodbye" if goodbye else "no frame from the host for 500 ms"
    assert f"timing: 1 timed call dropped ({why});" in _call(rt, "a2jDebug")[1].decode()


def test_virtual_line_noise_does_not_keep_the_failsafe_from_tripping() -> None:
    clock = Clock()
    rt, servo = _virtual(clock)
    limp = next(k for k in rt.config.keys if k.name == "servo.safe")  # type: ignore[attr-defined]
    rt.config.apply([(limp, "limp")])  # type: ignore[attr-defined]
    _call(rt, "a2j_set_servo", struct.pack("<b", SET))
    noise = damaged_frames(rt.index["a2jEcho"])  # type: ignore[attr-defined]
    for _ in range(150):  # 3 s of nothing but damaged frames, every 20 ms
        rt.feed(noise)  # type: ignore[attr-defined]
        rt.take_frames()  # type: ignore[attr-defined]
        clock.us += 20_000
        rt.poll()  # type: ignore[attr-defined]
    assert rt.failsafe.trips == 1 and servo.limp  # type: ignore[attr-defined]


def test_virtual_hold_keeps_the_last_command_as_the_firmware_does() -> None:
    """The virtual servo made safe with `hold` goes on to its last command (the firmware keeps
    its last pulse); it no longer stops where it happened to be, which hid a late command."""
    clock = Clock()
    rt, servo = _virtual(clock)
    _call(rt, "a2j_set_servo", struct.pack("<b", 127))
    clock.us += 20_000
    rt.poll()  # type: ignore[attr-defined]
    _call(rt, "a2jGoodbye")  # half-way there
    _run(rt, clock, 1_000_000)
    assert servo.position == servo.target == 90  # type: ignore[attr-defined]


# ---- the MicroPython firmware ------------------------------------------------------------------


@pytest.fixture
def mpy() -> Iterator[FirmwareSim]:
    s = FirmwareSim(RIG)
    try:
        yield s
    finally:
        s.close()


def _mpy_servo(sim: FirmwareSim) -> float:
    return float(sim.ctl("result = WORLD.pulse_us(15)") or 0.0)


def _reaches(sim: FirmwareSim, expr: str, n: int) -> Callable[[], bool]:
    return lambda: bool(sim.ctl(f"result = {expr}") >= n)


def _past(now_us: Callable[[], int], tick: int) -> bool:
    """Wait (without a frame to the board) until its clock is well past ``tick``."""
    return wait_for(lambda: now_us() >= tick + 500_000, 30)


@pytest.mark.slow
@pytest.mark.micropython
@pytest.mark.parametrize("goodbye", [True, False], ids=["goodbye", "silence"])
def test_micropython_a_timed_command_never_runs_after_the_host_has_gone(
    mpy: FirmwareSim, goodbye: bool
) -> None:
    board = Board(open_transport(mpy.url), timeout=5.0)
    try:
        board.handshake()
        board.call_ok("a2j_set_servo", struct.pack("<b", SET))
        held = _mpy_servo(mpy)
        assert held == 1217  # 1500 + -60 / 127 * 600, rounded
        tick = _timed(board, "a2j_set_servo", TIMED, 1_500_000)
        if goodbye:
            board.call_ok("a2jGoodbye")
    finally:
        board.close()  # the link closed: the host is gone
    assert _past(lambda: int(mpy.ctl("result = rt.clock()")), tick)
    assert _mpy_servo(mpy) == held  # (before: 1972, 3.01 s later, and held there)
    assert mpy.ctl("result = (rt.timing.cancelled, rt.timing.done)") == (1, 0)


@pytest.mark.slow
@pytest.mark.micropython
def test_micropython_line_noise_does_not_keep_the_failsafe_from_tripping(mpy: FirmwareSim) -> None:
    board = Board(open_transport(mpy.url), timeout=5.0)
    try:
        board.handshake()
        board.configure({"servo.safe": "limp"})
        board.call_ok("a2j_set_servo", struct.pack("<b", SET))
        noise = damaged_frames(board.index["a2jEcho"])
    finally:
        board.close()
    assert _mpy_servo(mpy) == 1217
    _noise_until(mpy.url, noise, lambda: _mpy_servo(mpy) == 0)  # limp: no pulse
    assert mpy.ctl("result = rt.failsafe.trips") == 1


def _noise_until(url: str, noise: bytes, safe: Callable[[], bool]) -> None:
    """Damaged frames every 20 ms, for 3 s at most, until ``safe()``; it must come."""
    host, port = url[len("tcp://") :].split(":") if url.startswith("tcp://") else ("", "")
    link = socket.create_connection((host, int(port)), timeout=5) if host else None
    raw = open_transport(url) if link is None else None
    try:
        end = time.monotonic() + 3.0
        while time.monotonic() < end:
            if link is not None:
                link.sendall(noise)
            else:
                assert raw is not None
                raw.write(noise)
            if safe():
                return
            time.sleep(0.02)
        raise AssertionError("3 s of damaged frames and the failsafe has not tripped")
    finally:
        if link is not None:
            link.close()
        if raw is not None:
            raw.close()


# ---- the AVR firmware ----------------------------------------------------------------------------


@pytest.fixture
def rig(avr_build: Path) -> Iterator[AvrSim]:
    sim = AvrSim(avr_build, avr_build / "uno_rig" / "firmware.elf")
    try:
        yield sim
    finally:
        sim.close()


def _avr_servo(rig: AvrSim) -> float:
    return float(rig.ctl("pulse").split()[1])


def _avr_now(rig: AvrSim) -> int:
    return int(rig.ctl("stats").split()[2])  # simulated µs (the board's clock starts after)


@pytest.mark.slow
@pytest.mark.avr
@pytest.mark.parametrize("goodbye", [True, False], ids=["goodbye", "silence"])
def test_avr_a_timed_command_never_runs_after_the_host_has_gone(rig: AvrSim, goodbye: bool) -> None:
    board = Board(open_transport(rig.url), timeout=5.0)
    try:
        board.handshake()
        board.call_ok("a2j_set_servo", struct.pack("<b", SET))
        held = _avr_servo(rig)
        assert held == pytest.approx(1216.5, abs=0.5)
        tick = _timed(board, "a2j_set_servo", TIMED, 1_500_000)
        edges = rig.ctl("trig").split()[1]  # and a camera pulse, handed to Timer2 (trigger.c)
        pulse = struct.pack("<qB", H0 + 1_400_000_000, board.index["a2j_trigger"]) + b"\x14\0"
        board.call_ok("a2jAt", pulse)
        if goodbye:
            board.call_ok("a2jGoodbye")
    finally:
        board.close()
    assert _past(lambda: _avr_now(rig), tick)
    assert _avr_servo(rig) == held  # (before: 1972 µs, and held there)
    assert rig.ctl("trig").split()[1] == edges
    cancelled = _peek_u32(rig, "timing_cancelled")
    board = Board(open_transport(rig.url), timeout=5.0)  # (a host again: to read what it said)
    try:
        board.handshake(describe=False)
        debug = board.call_ok("a2jDebug").decode()  # (64 bytes on AVR: the first said)
        done = struct.unpack("<BIIII", board.call_ok("a2jAlignInfo"))[3]
    finally:
        board.close()
    assert cancelled == 2 and done == 0
    if goodbye:
        assert debug.startswith("timing: 2 timed calls dropped (the host said goodbye);"), debug


def _peek_u32(rig: AvrSim, symbol: str) -> int:
    nm = subprocess.run(["avr-nm", str(rig.elf)], capture_output=True, text=True, check=True)
    addr = next(
        int(x.split()[0], 16) & 0xFFFF for x in nm.stdout.splitlines() if x.endswith(" " + symbol)
    )
    return int.from_bytes(
        bytes(int(b, 16) for b in rig.ctl(f"peek {addr:x}").split()[1:5]), "little"
    )


@pytest.mark.slow
@pytest.mark.avr
def test_avr_line_noise_does_not_keep_the_failsafe_from_tripping(rig: AvrSim) -> None:
    board = Board(open_transport(rig.url), timeout=5.0)
    try:
        board.handshake()
        board.configure({"servo.safe": "limp"})
        board.call_ok("a2j_set_servo", struct.pack("<b", SET))
        noise = damaged_frames(board.index["a2jEcho"])
    finally:
        board.close()
    assert _avr_servo(rig) != 0
    _noise_until(rig.url, noise, lambda: _avr_servo(rig) == 0)  # limp: no pulse
