"""J2A frame codec: golden vectors, properties over any payload/chunking, corruption."""

from __future__ import annotations

import random

from hypothesis import given, settings
from hypothesis import strategies as st

from missing_link.board import wire
from missing_link.j2a import codec
from missing_link.j2a.codec import (
    MAX_ENCODED_FRAME,
    SOF,
    SOS,
    Frame,
    FrameDecoder,
    FrameError,
    FrameErrorKind,
    FrameKind,
    checksum,
    encode_frame,
    xor_bytes,
)

from .vectors import NAMES, PROPS_REPLY_HEAD, PROPS_REQUEST, SIF, VECTORS, h


def decode_all(data: bytes) -> list[Frame | FrameError]:
    return FrameDecoder().feed(data)


def test_checksum_examples_from_spec() -> None:
    assert checksum(0, 0, b"") == 0x6A
    # The thesis text's example says 0xD5; the formula (and the original code) give 0x15 for it.
    assert encode_frame(SOF, 0, 0) == h("12 00 00 00 6a")


def test_every_golden_vector_encodes_and_decodes() -> None:
    for case, request, reply in VECTORS:
        for raw, kind in ((request, SOF), (reply, SOF)):
            (frame,) = decode_all(raw)
            assert isinstance(frame, Frame), case
            assert frame.kind == kind
            assert encode_frame(kind, frame.seq, frame.opcode, frame.payload) == raw, case


def test_mapping_vector_content() -> None:
    (frame,) = decode_all(VECTORS[0][2])
    assert isinstance(frame, Frame)
    assert frame.payload == NAMES and len(NAMES) == 0x5D


def test_properties_vector_header_and_sif_vector() -> None:
    (req,) = decode_all(PROPS_REQUEST)
    assert isinstance(req, Frame)
    assert (req.seq, req.opcode, req.payload) == (1, 1, h("02 00 00 00 00 00"))
    # The reply carries 45 bytes we do not have; rebuild one with the right header and check the
    # checksum logic reproduces the frame's structure.
    body = b"k\0v\0" * 11 + b"x"  # 45 bytes
    frame = encode_frame(SOF, 1, 0, PROPS_REPLY_HEAD[4:] + body)
    assert frame.startswith(PROPS_REPLY_HEAD)
    (sif,) = decode_all(SIF)
    assert isinstance(sif, Frame)
    assert sif.kind == FrameKind.SOS and sif.seq == 0 and sif.opcode == 13
    assert int.from_bytes(sif.payload[:8], "little") == 0x000660C6A1910116
    assert encode_frame(SOS, 0, 13, sif.payload) == SIF


def test_escapes_seen_on_the_wire() -> None:
    assert encode_frame(SOF, 0x12, 0xED, b"\x7d")[1:7] == h("7d 11 7d ec 01 7d")


def test_worst_case_frame_is_519_bytes() -> None:
    frame = encode_frame(SOF, 0x12, 0x12, b"\x12" * 255)
    # len 255 is not special, checksum may or may not be: the bound holds either way.
    assert len(frame) <= MAX_ENCODED_FRAME == 519
    worst = bytes([SOF]) + b"\x7d\x11" * 259
    assert len(worst) == 519


def test_encoder_rejects_bad_fields() -> None:
    for args in ((SOF, 0, 0, b"x" * 256), (SOF, 256, 0, b""), (0x13, 0, 0, b"")):
        try:
            encode_frame(*args)
        except ValueError as e:
            assert str(e)
        else:
            raise AssertionError(f"accepted {args}")


@given(st.binary(max_size=600))
def test_xor_bytes(data: bytes) -> None:
    x = 0
    for b in data:
        x ^= b
    assert xor_bytes(data) == x


frames_st = st.lists(
    st.tuples(
        st.sampled_from([SOF, SOS]),
        st.integers(0, 255),
        st.integers(0, 255),
        st.binary(max_size=255),
    ),
    min_size=1,
    max_size=8,
)


def chunked(data: bytes, cuts: list[int]) -> list[bytes]:
    points = sorted({c % (len(data) + 1) for c in cuts})
    out, last = [], 0
    for p in points:
        out.append(data[last:p])
        last = p
    out.append(data[last:])
    return out


@settings(max_examples=300)
@given(frames_st, st.lists(st.integers(0, 10_000), max_size=20))
def test_round_trip_any_payload_any_chunking(frames, cuts) -> None:  # type: ignore[no-untyped-def]
    stream = b"".join(encode_frame(*f) for f in frames)
    dec = FrameDecoder()
    got = []
    for piece in chunked(stream, cuts):
        got.extend(dec.feed(piece))
    assert got == [Frame(FrameKind(k), s, o, p) for k, s, o, p in frames]
    assert dec.stats.frames == len(frames) and dec.buffered == 0


@settings(max_examples=200)
@given(frames_st)
def test_board_and_host_codecs_agree(frames) -> None:  # type: ignore[no-untyped-def]
    for kind, seq, op, payload in frames:
        ours = encode_frame(kind, seq, op, payload)
        assert wire.encode_frame(kind, seq, op, payload) == ours
        parser = wire.FrameParser()
        events = parser.feed(ours)
        if kind == SOF:
            assert events == [(wire.EV_REQUEST, seq, op, payload)]
        else:
            assert events == []  # a board ignores SIF frames


def test_a_sif_frame_spelling_the_break_is_not_a_break() -> None:
    # Found by the property test above: the board parser took an ignored SIF frame's payload for
    # bytes between frames.  It now walks the frame (escaped length included) and hunts after it.
    parser = wire.FrameParser()
    sif = encode_frame(SOS, 0, 0, wire.BREAK + b"\r")
    long_sif = encode_frame(SOS, 1, 2, bytes(0x12) + wire.BREAK + b"\n")  # the length escaped
    assert parser.feed(sif + long_sif) == []
    # After a SIF frame, the parser is between frames again: a real break still counts.
    assert parser.feed(wire.BREAK + b"\r") == [(wire.EV_BREAK, None, 0, None)]
    assert parser.feed(encode_frame(SOF, 3, 4, b"x")) == [(wire.EV_REQUEST, 3, 4, b"x")]


def test_a_cut_sif_frame_is_dropped_at_silence_and_the_break_after_it_counts() -> None:
    # (review: a SIF cut short, or one stray 0xED of noise, had no timeout: it counted up to 259
    # bytes on, and swallowed the break flash sends after 50 ms of quiet)
    for cut in (b"\xed", b"\xed\x00\x05\xff\x01\x02", b"\xed\x00\x05\x08"):
        parser = wire.FrameParser()
        assert parser.feed(cut) == [] and parser.in_frame()
        assert parser.abort() is None and parser.abort() is None  # (dropped; its rest skipped)
        assert not parser.in_frame() and parser.errors == 0
        assert parser.feed(b"\r" + wire.BREAK + b"\r") == [(wire.EV_BREAK, None, 0, None)]
    # the rest of a cut SIF that spells the break, after one silence, is still no break
    parser = wire.FrameParser()
    parser.feed(b"\xed\x00\x00\x07\x03\x03")
    parser.abort()
    assert parser.feed(b"repl\r") == []


_breaky = st.lists(st.sampled_from([wire.BREAK + b"\r", wire.BREAK + b"\n", b"\x12", b"\xed",
                                     b"\x7d", b"x"]), max_size=6).map(b"".join)  # fmt: skip


@settings(max_examples=300)
@given(st.lists(st.tuples(st.sampled_from([SOF, SOS]), st.integers(0, 255),
                          st.integers(0, 255), _breaky), max_size=8))  # fmt: skip
def test_a_stream_of_frames_is_its_requests_whatever_the_payloads_spell(frames) -> None:  # type: ignore[no-untyped-def]
    """Whole frames back to back, SIFs among them, payloads full of the break and of markers:
    the board hears exactly the requests, in order, and never a break."""
    parser = wire.FrameParser()
    got = parser.feed(b"".join(encode_frame(*f) for f in frames))
    assert got == [(wire.EV_REQUEST, s, o, p) for k, s, o, p in frames if k == SOF]


@settings(max_examples=300)
@given(frames_st, st.binary(max_size=40), st.integers(0, 2**32))
def test_junk_and_corruption_never_raise_and_resync(frames, junk, seed) -> None:  # type: ignore[no-untyped-def]
    rng = random.Random(seed)
    stream = bytearray(junk.replace(b"\x12", b"").replace(b"\xed", b""))
    for f in frames:
        stream += encode_frame(*f)
    # Corrupt a few random bytes, then append one clean frame that must always come through.
    for _ in range(rng.randint(0, 4)):
        if stream:
            stream[rng.randrange(len(stream))] = rng.randrange(256)
    tail = encode_frame(SOF, 7, 9, b"tail")
    dec = FrameDecoder()
    out = []
    for piece in chunked(bytes(stream) + tail, [rng.randrange(1000) for _ in range(5)]):
        out.extend(dec.feed(piece))
    assert out and out[-1] == Frame(FrameKind.SOF, 7, 9, b"tail")
    s = dec.stats
    errors = [e for e in out if isinstance(e, FrameError)]
    assert s.bad_checksums + s.bad_escapes + s.cut_frames == len(errors)


def test_junk_is_counted() -> None:
    dec = FrameDecoder()
    out = dec.feed(b"hello" + encode_frame(SOF, 1, 2, b"x"))
    assert len(out) == 1 and dec.stats.junk_bytes == 5


def test_bad_checksum_reported_with_seq() -> None:
    raw = bytearray(encode_frame(SOF, 5, 4, b"abc"))
    raw[-1] ^= 0x01
    (err,) = decode_all(bytes(raw))
    assert isinstance(err, FrameError)
    assert err.kind == FrameErrorKind.CHECKSUM and err.seq == 5


def test_bad_escape_value_is_checked() -> None:
    # 7d 00 would unescape to 0x01, which is not special: a framing error (the original missed it).
    raw = h("12 05 04 02 7d 00 41") + b"\x00"
    dec = FrameDecoder()
    (err,) = dec.feed(raw)
    assert isinstance(err, FrameError) and err.kind == FrameErrorKind.ESCAPE
    assert dec.stats.bad_escapes == 1


def test_cut_frame_restarts_at_marker() -> None:
    good = encode_frame(SOF, 9, 4, b"ok")
    raw = h("12 05 04 05 61 62") + good
    (err, frame) = decode_all(raw)
    assert isinstance(err, FrameError) and err.kind == FrameErrorKind.CUT and err.seq == 5
    assert frame == Frame(FrameKind.SOF, 9, 4, b"ok")


def test_cut_frame_waits_only_as_long_as_needed() -> None:
    dec = FrameDecoder()
    assert dec.feed(h("12 05 04 05 61")) == []
    assert dec.in_frame()
    err = dec.abort_frame()
    assert err is not None and err.seq == 5 and not dec.in_frame()


def test_board_parser_reports_errors_with_seq() -> None:
    p = wire.FrameParser()
    bad = bytearray(encode_frame(SOF, 3, 4, b"z"))
    bad[-1] ^= 0xFF
    assert p.feed(bytes(bad)) == [(wire.EV_CHECKSUM, 3, 4, None)]
    assert p.feed(h("12 08 04 05 61") + h("12 09 04 00") + bytes([checksum(9, 4, b"")])) == [
        (wire.EV_CUT, 8, 0, None),
        (wire.EV_REQUEST, 9, 4, b""),
    ]
    assert p.feed(h("12 0a 04 01 7d 33")) == [(wire.EV_ESCAPE, 10, 0, None)]


def test_codec_module_has_no_io() -> None:
    assert "socket" not in vars(codec) and "time" not in vars(codec)
