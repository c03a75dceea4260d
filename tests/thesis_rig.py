"""The thesis rig (examples/boards/thesis-rig.py; thesis-rig-uno.py on AVR; the ``thesis`` sim on
CPython) looked at from outside its link, on every runtime: where its servo is, what its Python
runtime holds, a counter of the AVR image, and what a host sends it that no host should."""

from __future__ import annotations

import struct
import subprocess
from typing import Any

import pytest

from missing_link.host.board import Board
from missing_link.j2a import SOF, SOS, encode_frame
from missing_link.testing import RuntimeBoard, replies
from missing_link.transport import Transport

H0 = 1_795_000_000_000_000_000  # host ns of the pushed map's reference (any epoch)
SET, TIMED = -60, 100  # the servo's command now, and one for later
#: the servo's pulse at SET (µs): 1500 + -60 / 127 * 600 (MicroPython rounds it; the virtual
#: servo's horn is at -60 / 127 * 90 degrees)
HELD = {
    "cpython": pytest.approx(1500 - 60 / 127 * 600),
    "micropython": 1217,
    "avr": pytest.approx(1216.5, abs=0.5),
}


def servo_us(rig: RuntimeBoard) -> float:
    """The rig's servo pulse (µs); 0: no pulse (limp)."""
    if rig.runtime == "micropython":
        return float(rig.ctl("result = WORLD.pulse_us(15)") or 0.0)  # type: ignore[attr-defined]
    if rig.runtime == "avr":
        return float(rig.ctl("pulse").split()[1])  # type: ignore[attr-defined]
    servo = driver(rig, "servo")  # (no pulse before its first command, as on the firmware)
    return 0.0 if servo.limp or not servo.commands else 1500 + servo.position * 600 / 90


def driver(rig: RuntimeBoard, name: str) -> Any:
    """The virtual driver of transducer ``name`` (CPython)."""
    return next(t for t in rig.rt.transducers if t.name == name).driver  # type: ignore[attr-defined]


def inside(rig: RuntimeBoard, expr: str) -> Any:
    """``expr`` on the board's runtime (``rt``), where it is Python; None on AVR."""
    if rig.runtime == "micropython":
        return rig.ctl(f"result = {expr}")  # type: ignore[attr-defined]
    if rig.runtime == "cpython":
        return eval(expr, {"rt": rig.rt})  # type: ignore[attr-defined]
    return None


def peek_u32(rig: RuntimeBoard, symbol: str) -> int:
    """A uint32_t of the AVR image's static RAM, by its symbol."""
    elf = str(rig.elf)  # type: ignore[attr-defined]
    nm = subprocess.run(["avr-nm", elf], capture_output=True, text=True, check=True)
    addr = next(
        int(x.split()[0], 16) & 0xFFFF for x in nm.stdout.splitlines() if x.endswith(" " + symbol)
    )
    peek = rig.ctl(f"peek {addr:x}")  # type: ignore[attr-defined]
    return int.from_bytes(bytes(int(b, 16) for b in peek.split()[1:5]), "little")


def timed_map(board: Board) -> int:
    """Hand the board a map whose H0 is its time now; that board time."""
    now = board.clock_exchange(5.0).t3
    board.call_ok("a2jHostMap", struct.pack("<Qqi", now, H0, 0))
    return now


def at(index: dict[str, int], name: str, host_ns: int, payload: bytes = b"") -> bytes:
    """An a2jAt's payload: ``name`` called with ``payload`` at ``host_ns``."""
    return struct.pack("<qB", host_ns, index[name]) + payload


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


def drain(line: Transport) -> bytes:
    """All the board has sent on ``line`` by now."""
    out = b""
    while chunk := line.read(0):
        out += chunk
    return out


def reply_on(rig: RuntimeBoard, line: Transport, seq: int) -> Any:
    """The board's reply (a SOF frame) with ``seq`` on a raw ``line``, board time passing until
    it is there (within 5 s)."""
    got = bytearray()

    def there() -> object:
        got.extend(drain(line))
        return replies(bytes(got), seq)

    assert rig.run_until(there, 5_000_000), f"no reply {seq} in 5 s: {bytes(got).hex()}"
    return replies(bytes(got), seq)[0]


#: ``wait_us(us)`` in the MicroPython firmware's interpreter: the board's clock passing
_MPY_WAIT = (
    "import time\n"
    "def wait_us(us):\n"
    "    t = time.ticks_us()\n"
    "    while time.ticks_diff(time.ticks_us(), t) < us:\n"
    "        pass\n"
)


def run_inside(rig: RuntimeBoard, code: str) -> Any:
    """Run ``code`` in the board's Python runtime (``rt``; ``wait_us(us)``: board time passing,
    nothing else running meanwhile) and give back its ``result``: what a test of the runtime's
    own timing does where no link could keep to it."""
    if rig.runtime == "micropython":
        return rig.ctl(_MPY_WAIT + code)  # type: ignore[attr-defined]
    scope = {"rt": rig.rt, "wait_us": rig.clock.advance}  # type: ignore[attr-defined]
    exec(code, scope)
    return scope["result"]
