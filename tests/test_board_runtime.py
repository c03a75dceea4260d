"""Board runtime (CPython side of the MicroPython code): vectors, errors, clock, limits."""

from __future__ import annotations

import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from missing_link.board.clock import WrappingClock
from missing_link.board.runtime import INTERBYTE_TIMEOUT_US, BoardRuntime, Transducer
from missing_link.board.wire import encode_frame as board_encode_frame
from missing_link.board.wire import encode_frame_head, encode_frame_tail
from missing_link.j2a import SOF, Frame, FrameDecoder, FrameKind, encode_frame, parse_mapping
from missing_link.testing import wait_for
from missing_link.virtual.sims import original

from .vectors import ORIGINAL_TABLE, PROPS_REPLY_HEAD, PROPS_REQUEST, SIF, VECTORS


class FakeTicks:
    def __init__(self, period: int) -> None:
        self.period = period
        self.t = 0

    def __call__(self) -> int:
        return self.t % self.period


def frames(rt: BoardRuntime) -> list[Frame]:
    out = FrameDecoder().feed(rt.take_output())
    assert all(isinstance(f, Frame) for f in out)
    return out  # type: ignore[return-value]


def test_original_sim_reproduces_golden_vectors() -> None:
    rt = original(epoch="e")
    assert [n for n, _k, _h in rt.functions] == ORIGINAL_TABLE
    for case, request, reply in VECTORS:
        rt.feed(request)
        assert rt.take_output() == reply, case
    rt.feed(PROPS_REQUEST)
    out = rt.take_output()
    assert out[:3] == PROPS_REPLY_HEAD[:3] and out[4:10] == PROPS_REPLY_HEAD[4:]


def test_sif_vector_layout() -> None:
    clock = FakeTicks(1 << 62)
    clock.t = 0x000660C6A1910116
    rt = BoardRuntime("b", "m", "s", epoch="e", clock=clock)

    class Drv:
        def set_cb(self, fn):  # type: ignore[no-untyped-def]
            self.fn = fn

    d = Drv()
    rt.add_transducer(Transducer("quad", 13, "quad", "HEDS-6500", 1, "int16_t", -1), d)
    d.fn(0, 0)
    rt.poll()
    assert rt.take_output() == SIF


def test_error_frames_for_damaged_requests() -> None:
    rt = BoardRuntime("b", "m", "s", epoch="e")
    bad = bytearray(encode_frame(SOF, 9, 4, b"x"))
    bad[-1] ^= 1
    rt.feed(bytes(bad))
    (f,) = frames(rt)
    assert (f.seq, f.opcode, len(f.payload)) == (9, 0xF3, 2)
    rt.feed(bytes.fromhex("12 0a 04 01 7d 33".replace(" ", "")))
    (f,) = frames(rt)
    assert (f.seq, f.opcode) == (10, 0xF4)
    rt.feed(bytes.fromhex("120b0402") + encode_frame(SOF, 12, 4, b""))
    cut, echo = frames(rt)
    assert (cut.seq, cut.opcode) == (11, 0xF2) and (echo.seq, echo.opcode) == (12, 0xBA)


def test_interbyte_silence_aborts_frame_with_f2() -> None:
    clock = FakeTicks(1 << 62)
    rt = BoardRuntime("b", "m", "s", epoch="e", clock=clock)
    rt.feed(bytes.fromhex("12050403"))
    clock.t += INTERBYTE_TIMEOUT_US + 1
    rt.poll()
    (f,) = frames(rt)
    assert (f.seq, f.opcode) == (5, 0xF2)
    assert rt.parser.in_frame()  # what still comes of the frame is skipped (wire.py) ...
    clock.t += INTERBYTE_TIMEOUT_US + 1
    rt.poll()
    assert not rt.parser.in_frame() and rt.take_output() == b""  # ... until the line is quiet


def test_sif_frames_ignored_by_board() -> None:
    rt = BoardRuntime("b", "m", "s", epoch="e")
    rt.feed(SIF)
    assert rt.take_output() == b""


def test_mapping_over_255_bytes_is_readable_in_full() -> None:
    rt = BoardRuntime("b", "m", "s", epoch="e")
    for i in range(30):
        rt.add_function(f"function_with_a_long_name_{i:02d}", lambda p: (0, b""))
    rt.feed(encode_frame(SOF, 0, 0))
    (f,) = frames(rt)
    head = parse_mapping(f.payload)  # opcode 0 stops at a name boundary
    assert len(f.payload) <= 255 and "a2jGetMappingMany" in head
    full = rt.mapping_blob()
    assert len(full) > 255 and parse_mapping(full)[-1] == "function_with_a_long_name_29"


def test_function_table_rules() -> None:
    rt = BoardRuntime("b", "m", "s", epoch="e")
    with pytest.raises(ValueError, match="twice"):
        rt.add_function("a2jEcho", lambda p: (0, b""))
    rt.add_function("bad", lambda p: (0xF3, b""))  # reserved code: replaced by 0xFF
    rt.add_function("boom", lambda p: 1 / 0)
    rt.feed(encode_frame(SOF, 1, rt.index["bad"]) + encode_frame(SOF, 2, rt.index["boom"]))
    a, b, *said = frames(rt)
    assert a.opcode == 0xFF and b.opcode == 0xFF
    # and each said once in the board's log (ERROR), after the replies (board/log.py)
    assert [(f.kind, f.opcode, f.payload[8]) for f in said] == [(FrameKind.SOS, 0xFE, 40)] * 2
    assert b"reserved code 243" in said[0].payload and b"ZeroDivisionError" in said[1].payload
    rt.feed(encode_frame(SOF, 3, rt.index["a2jDebug"]))
    (dbg,) = frames(rt)
    assert b"reserved" in dbg.payload and b"boom" in dbg.payload


def test_transducer_that_cannot_fit_one_sif_is_refused() -> None:
    with pytest.raises(ValueError, match="one SIF carries 255"):
        Transducer("big", 1, "p", "M", 22, "uint32_t", 0)
    Transducer("ok", 1, "p", "M", 21, "uint32_t", 0)


def test_clock_extends_wrapping_ticks_to_64_bit() -> None:
    ticks = FakeTicks(1 << 16)
    clock = WrappingClock(ticks, 1 << 16)
    seen = []
    for _ in range(1000):
        ticks.t += 1000  # read well inside half a period
        seen.append(clock())
    assert seen == [1000 * (k + 1) for k in range(1000)]
    assert seen[-1] > (1 << 16) * 15  # wrapped 15 times, never went backwards
    ticks.t -= 5  # an older read (e.g. from an interrupt) never steps back
    assert clock() == seen[-1]


def test_properties_and_transds_blobs() -> None:
    rt = BoardRuntime("b", "m", "s", epoch="e")
    rt.add_transducer(Transducer("x", 3, "p", "M", 2, "float", 0.5, unit="m", rate_hz=10))
    text = rt.transds_blob().decode()
    assert text == "transds/1\nx,3,p,M,2,float,0.5,unit=m,rate_hz=10\n"
    props = rt.properties
    for key in (
        "j2a.version",
        "board.name",
        "board.model",
        "board.serial",
        "clock.epoch",
        "clock.res_us",
        "fw.version",
    ):
        assert key in props


# ---- error paths, byte for byte as the 2014 firmware (spec 1.11) -------------------------------
def test_cut_frame_gets_exactly_one_error_frame() -> None:
    rt = original(epoch="e")
    echo = encode_frame(SOF, 6, 4, b"")
    for cut in ("12050403aa", "120504", "1205", "12050403aa7d"):
        rt.feed(bytes.fromhex(cut) + echo)
        got = frames(rt)
        assert [(f.seq, f.opcode) for f in got] == [(5, 0xF2), (6, 0xBA)], cut
    rt.feed(bytes.fromhex("12") + echo)  # no seq yet: nothing to answer, as the original
    assert [(f.seq, f.opcode) for f in frames(rt)] == [(6, 0xBA)]


def test_a2jmany_short_header_is_echoed_like_the_original() -> None:
    rt = original(epoch="e")
    rt.feed(encode_frame(SOF, 5, 1, b"\x02\x00"))
    assert rt.take_output() == bytes.fromhex("1205ff0202006e")


def test_properties_with_the_write_flag_answer_flags_00() -> None:
    rt = original(epoch="e")
    rt.feed(encode_frame(SOF, 3, 1, bytes([2, 0x02, 0, 0, 0, 0])))
    (f,) = frames(rt)
    assert f.opcode == 0 and f.payload[1] == 0x00  # flags byte 00, as the original


def test_escapes_we_reject_on_purpose() -> None:
    """7D FF: the original answers F2, we answer F4 (spec 1.3 requires the check).  7D 00 the
    original accepted as 0x01; we answer F4 (docs/protocol-differences.md)."""
    rt = original(epoch="e")
    for esc in ("7dff", "7d00"):
        rt.feed(bytes.fromhex("120904" + "01" + esc + "00"))
        got = frames(rt)
        assert [(f.seq, f.opcode) for f in got] == [(9, 0xF4)], esc


def test_silence_after_sof_gets_f2_over_a_real_pty() -> None:
    import os
    import select
    import tty

    from missing_link.virtual import start_board_thread

    server, thread = start_board_thread(original(epoch="e"), "pty")
    fd = os.open(server.url.removeprefix("serial://"), os.O_RDWR | os.O_NOCTTY)
    try:
        tty.setraw(fd)
        os.write(fd, bytes.fromhex("120e"))  # SOF, seq 0x0e, then nothing
        got = bytearray()

        def answered() -> bool:
            if select.select([fd], [], [], 0)[0]:
                got.extend(os.read(fd, 4096))
            return b"\x12\x0e\xf2" in got

        assert wait_for(answered, 5), got
        (f,) = [f for f in FrameDecoder().feed(got) if isinstance(f, Frame) and f.kind == SOF]
        assert (f.seq, f.opcode, len(f.payload)) == (0x0E, 0xF2, 2)
    finally:
        os.close(fd)
        server.stop()
        thread.join(5)


@settings(max_examples=200, deadline=None)
@given(seq=st.integers(0, 255), t2=st.integers(0, 2**64 - 1), t3=st.integers(0, 2**64 - 1))
def test_clock_reply_encoded_in_two_parts_is_the_whole_frame(seq: int, t2: int, t3: int) -> None:
    """a2jClock's reply is encoded up to t2 when the request arrives and finished with t3 at the
    hand-off: byte for byte the frame a single encode gives, which the host decodes (stamps with
    escaped bytes included)."""
    head, c = encode_frame_head(SOF, seq, 0, 16, struct.pack("<Q", t2))
    got = bytes(encode_frame_tail(head, c, struct.pack("<Q", t3)))
    assert got == board_encode_frame(SOF, seq, 0, struct.pack("<QQ", t2, t3))
    (frame,) = FrameDecoder().feed(got)
    assert isinstance(frame, Frame) and frame.seq == seq and frame.opcode == 0
    assert struct.unpack("<QQ", frame.payload) == (t2, t3)


def test_error_paths_against_the_original_firmwares_bytes() -> None:
    """docs/protocol-differences.md, row by row, against what the 2014 firmware answered
    (tests/vectors.py): identical, the same but for the diagnostic u16 (a source line there),
    or different on purpose."""
    import time

    from .vectors import ORIGINAL_ERROR_PATHS, ORIGINAL_OFFSET_300, h

    def ours(request: bytes) -> bytes:
        rt = original(epoch="e")
        rt.feed(request)
        out = bytes(rt.take_output())
        time.sleep(0.02)  # past the board's 10 ms receive timeout
        rt.poll()
        return out + bytes(rt.take_output())

    def shape(data: bytes) -> list[tuple[int, int, int]]:
        return [(f.seq, f.opcode, len(f.payload)) for f in FrameDecoder().feed(data)]

    got = {case: (ours(req), theirs) for case, req, theirs in ORIGINAL_ERROR_PATHS}
    # identical, byte for byte
    for case in ("a2jMany with a 2-byte payload", "a2jGetProperties through a2jMany with isWrite"):
        assert got[case][0] == got[case][1], case
    # the same frame; only the diagnostic differs
    for case in ("SOF and seq, then silence", "bad checksum", "no function 200"):
        assert shape(got[case][0]) == shape(got[case][1]), case
    # different on purpose
    assert got["lone SOF, then silence"] == (b"", h("12 0e f2 02 01 25 b4"))
    mine, theirs = got["cut frame, then a good echo"]
    assert shape(mine) == [(5, 0xF2, 2), (6, 0xBA, 0)] and shape(theirs) == [(5, 0xF2, 2)]
    assert shape(got["escape 7D FF in a payload"][0]) == [(8, 0xF4, 2)]
    assert shape(got["escape 7D FF in a payload"][1]) == [(8, 0xF2, 2)]
    assert shape(got["escape 7D 00 in a payload"][0]) == [(8, 0xF4, 2)]
    assert got["escape 7D 00 in a payload"][1] == h("12 08 ba 01 01 ae")  # taken as 0x01
    # the emulated original has the offset bug: offset 300 gives the data of offset 44
    request, head = ORIGINAL_OFFSET_300
    at_44 = ours(encode_frame(SOF, 9, 1, bytes([8, 0]) + (44).to_bytes(4, "little")))
    reply = ours(request)
    assert reply.startswith(head) and reply[10:][:-1] == at_44[10:][:-1]
