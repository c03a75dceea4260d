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
from missing_link.j2a import SOF, Frame, FrameDecoder, FrameKind, encode_frame

from .helpers import HexLinePipe, read_blob_raw
from .vectors import (
    CONFIG_KEYS,
    CONFIG_VECTORS,
    ORIGINAL_TABLE,
    PROPS_REPLY_HEAD,
    PROPS_REQUEST,
    VECTORS,
)

ROOT = Path(__file__).resolve().parent.parent
MPY_PKG = ROOT / "node_modules" / "@micropython" / "micropython-webassembly-pyscript"
pytestmark = [pytest.mark.micropython, pytest.mark.slow]


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


def test_run_time_configuration_golden_vectors_on_micropython() -> None:
    """The configuration functions answer byte for byte as on CPython (tests/vectors.py), and
    the key table is the same."""
    pipe = _start("setup_config.py")
    try:
        blob = read_blob_raw(pipe.exchange, 11, len(CONFIG_KEYS))
        assert blob == CONFIG_KEYS
        for case, request, reply in CONFIG_VECTORS:
            assert pipe.exchange(request) == reply, case
    finally:
        pipe.close()


def test_a_power_cut_in_a_save_on_micropython_leaves_old_or_new() -> None:
    """The record goes to a real file on MicroPython's filesystem, through a temporary file and
    a rename: power lost after any part of the new record, or before the rename, and the board
    boots with the old configuration; a save that completed is there after a reboot."""
    pipe = _start("setup_config.py")
    set_rate = lambda seq, hz: encode_frame(SOF, seq, 13, b"\x01\x01" + struct.pack("<f", hz))  # noqa: E731
    get = encode_frame(SOF, 99, 12, b"")
    try:
        assert pipe.exchange(set_rate(1, 20.0)) == encode_frame(SOF, 1, 0, b"")  # saved: 20
        for k, cut in enumerate(("CUT 0", "CUT 5", "CUT 17", "CUT 24", "CUTRENAME")):
            pipe.command(cut)
            assert pipe.command(set_rate(2 + k, 30.0).hex()) == "CUT", cut
            pipe.command("REBOOT")
            rate = struct.unpack_from("<f", pipe.exchange(get), 4 + 3 + 4)[0]
            assert rate == 20.0, cut  # the old configuration, whole
        assert pipe.exchange(set_rate(20, 40.0)) == encode_frame(SOF, 20, 0, b"")
        pipe.command("REBOOT")
        reply = pipe.exchange(get)
        assert struct.unpack_from("<f", reply, 11)[0] == 40.0 and reply[6] & 3 == 3
    finally:
        pipe.close()
