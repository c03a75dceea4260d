"""The board runtime runs unchanged on real MicroPython (1.27, WebAssembly port from npm, under
node): it reproduces the golden vectors and serves the real host client, a2jMany included."""

from __future__ import annotations

import shutil
import struct
from collections.abc import Iterator
from pathlib import Path

import pytest

from missing_link.errors import CallError
from missing_link.host.board import Board
from missing_link.j2a import Frame, FrameDecoder, FrameKind

from .helpers import HexLinePipe, read_blob_raw
from .vectors import ORIGINAL_TABLE, PROPS_REPLY_HEAD, PROPS_REQUEST, VECTORS

ROOT = Path(__file__).resolve().parent.parent
MPY_PKG = ROOT / "node_modules" / "@micropython" / "micropython-webassembly-pyscript"
pytestmark = pytest.mark.micropython


def _start(setup: str) -> HexLinePipe:
    if shutil.which("node") is None or not MPY_PKG.exists():
        pytest.fail("node and the npm MicroPython package are required: run `make node`")
    return HexLinePipe(
        [
            "node",
            str(ROOT / "tests" / "micropython" / "board_host.mjs"),
            str(ROOT / "src" / "missing_link" / "board"),
            str(ROOT / "tests" / "micropython" / setup),
        ]
    )


@pytest.fixture
def mpy_board() -> Iterator[HexLinePipe]:
    pipe = _start("setup_board.py")
    try:
        yield pipe
    finally:
        pipe.close()


def test_clock_and_host_map_on_micropython() -> None:
    """a2jClock answers two ordered 64-bit stamps; the host's map is taken and inverted in
    integer maths exactly as on CPython."""
    pipe = _start("setup_part2.py")
    board = Board(pipe, timeout=10.0)
    try:
        board.handshake()
        ex = board.clock_exchange(10.0)
        assert 0 <= ex.t2 <= ex.t3 and ex.t1 <= ex.t4
        b0, h0, ppb = 5_000_000_123, 1_700_000_000_000_000_000, 48_500
        board.call_ok("a2jHostMap", struct.pack("<Qqi", b0, h0, ppb))
        assert struct.unpack("<Qqi", board.call_ok("a2jHostMap")) == (b0, h0, ppb)
        for dt_ns in (0, 1_000, 123_456_789, 86_400 * 10**9):
            got = struct.unpack("<Q", board.call_ok("boardTimeAt", struct.pack("<q", h0 + dt_ns)))
            assert got[0] == b0 + (dt_ns * 10**6) // (10**9 + ppb)
    finally:
        board.close()
        pipe.close()


def test_runs_on_micropython_with_wrapping_clock(mpy_board: HexLinePipe) -> None:
    assert mpy_board.ident.startswith("micropython 1.27")
    assert "clock=WrappingClock" in mpy_board.ident  # ticks_us extended to 64 bit


def test_golden_vectors_on_micropython(mpy_board: HexLinePipe) -> None:
    for case, request, reply in VECTORS:
        assert mpy_board.exchange(request) == reply, case
    out = mpy_board.exchange(PROPS_REQUEST)
    assert out[:4] == PROPS_REPLY_HEAD[:3] + out[3:4] and out[4:10] == PROPS_REPLY_HEAD[4:]


def test_host_client_against_micropython_board(mpy_board: HexLinePipe) -> None:
    # 1000 bytes in 5 chunks, offsets past 255: our runtime serves them (the 2014 firmware did
    # not) -- raw, before the host's reader owns the pipe
    blob = read_blob_raw(mpy_board.exchange, ORIGINAL_TABLE.index("bigBlob"), 1000)
    assert blob == bytes((i * 7 + 3) & 0xFF for i in range(1000))
    board = Board(mpy_board, timeout=10.0)
    try:
        board.handshake()
        assert board.functions == ORIGINAL_TABLE
        assert board.is_original and board.properties["board.name"] == "mpy"
        assert board.transducers is None  # Part 1 board: no descriptors
        # the host, meeting a Part 1 board, stops before offset 256 naming the bug
        with pytest.raises(CallError, match="offset bug"):
            board.read_many("bigBlob")
        payload = bytes(range(255))
        assert board.call("a2jEcho", payload).payload == payload
        (now,) = struct.unpack("<Q", board.call_ok("getTime"))
        assert now > 0
    finally:
        board.close()


def test_sample_sif_from_micropython(mpy_board: HexLinePipe) -> None:
    mpy_board.send_line("PULSE1234")
    (frame,) = FrameDecoder().feed(mpy_board.read(10.0))
    assert isinstance(frame, Frame) and frame.kind == FrameKind.SOS
    assert frame.opcode == 13 and frame.seq == 0  # cmd = transducer id, board SIF counter
    stamp, value = struct.unpack("<Qh", frame.payload)
    assert value == 1234 and stamp >= 0
