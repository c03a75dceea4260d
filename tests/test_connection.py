"""Host connection state machine, driven against the board runtime with virtual time."""

from __future__ import annotations

import random

from hypothesis import given, settings
from hypothesis import strategies as st

from missing_link.board.runtime import BoardRuntime, Transducer
from missing_link.j2a import (
    SOF,
    SOS,
    CallCompleted,
    CallFailed,
    FailureReason,
    FrameDamaged,
    HostConnection,
    SifReceived,
    TransferCompleted,
    TransferProgress,
    encode_frame,
)
from missing_link.j2a.blobs import many_request
from missing_link.testing import FakeBoardClock


def make_board(blob: bytes = b"") -> BoardRuntime:
    rt = BoardRuntime("b", "m", "s", epoch="e", clock=FakeBoardClock())
    rt.add_blob_function("blob", lambda: blob)
    return rt


class Link:
    """Host connection <-> board runtime with optional byte chunking between them."""

    def __init__(self, rt: BoardRuntime, conn: HostConnection, rng: random.Random | None = None):
        self.rt, self.conn, self.rng = rt, conn, rng
        self.now = 0.0
        self.events: list[object] = []

    def run(self, rounds: int = 200) -> list[object]:
        for _ in range(rounds):
            for frame in self.conn.data_to_send():
                self.rt.feed(frame)
            self.rt.poll()
            out = self.rt.take_output()
            if not out and not self.conn.pending():
                break
            pieces = [out]
            if self.rng and out:
                cut = sorted(self.rng.randrange(len(out) + 1) for _ in range(3))
                pieces = [out[: cut[0]], out[cut[0] : cut[1]], out[cut[1] : cut[2]], out[cut[2] :]]
            for piece in pieces:
                self.events += self.conn.receive_data(piece, self.now)
            self.now += 0.001
        return self.events


def idx(rt: BoardRuntime, name: str) -> int:
    return rt.index[name]


def _leads(events: list[object]) -> bool:
    """Whether a reply says it headed the read (``CallCompleted.lead``)."""
    return any(isinstance(e, CallCompleted) and e.lead for e in events)


def test_call_and_seq_advances_per_request() -> None:
    rt, conn = make_board(), HostConnection()
    link = Link(rt, conn)
    a = conn.call(idx(rt, "a2jEcho"), b"one", 0.0, 1.0)
    b = conn.call(idx(rt, "a2jEcho"), b"two", 0.0, 1.0)
    events = link.run()
    assert events == [CallCompleted(a, 0xBA, b"one"), CallCompleted(b, 0xBA, b"two")]
    assert conn.stats.requests == 2 and conn._seq == 2


def test_window_one_keeps_a_single_request_in_flight() -> None:
    conn = HostConnection()
    conn.call(4, b"", 0.0, 1.0)
    conn.call(4, b"", 0.0, 1.0)
    assert len(conn.data_to_send()) == 1 and conn.pending() == 2


def test_timeout_then_late_reply_is_discarded_not_given_to_next_call() -> None:
    rt, conn = make_board(), HostConnection()
    first = conn.call(idx(rt, "a2jEcho"), b"old", 0.0, 0.1)
    (req,) = conn.data_to_send()
    assert conn.get_timer() == 0.1
    events = conn.handle_timer(0.2)
    assert events == [CallFailed(first, FailureReason.TIMEOUT, None, "no reply within 100 ms")]
    second = conn.call(idx(rt, "a2jEcho"), b"new", 0.2, 1.0)
    rt.feed(req)  # the board answers the old request only now
    for f in conn.data_to_send():
        rt.feed(f)
    events = conn.receive_data(rt.take_output(), 0.3)
    assert events == [CallCompleted(second, 0xBA, b"new")]
    assert conn.stats.late_replies == 1 and conn.stats.timeouts == 1


def test_foreign_reply_is_counted() -> None:
    conn = HostConnection()
    assert conn.receive_data(encode_frame(SOF, 99, 0, b"x"), 0.0) == []
    assert conn.stats.foreign_replies == 1


def test_board_error_index_out_of_bounds() -> None:
    rt, conn = make_board(), HostConnection()
    op = conn.call(200, b"", 0.0, 1.0)
    (ev,) = Link(rt, conn).run()
    assert isinstance(ev, CallFailed) and ev.reason is FailureReason.BOARD_ERROR
    assert ev.code == 0xF0 and "out of bounds" in ev.detail and ev.op == op


def test_damaged_request_is_retried_with_fresh_seq() -> None:
    rt, conn = make_board(), HostConnection(retries=2)
    op = conn.call(idx(rt, "a2jEcho"), b"hi", 0.0, 1.0)
    (frame,) = conn.data_to_send()
    bad = bytearray(frame)
    bad[-1] ^= 0x55  # the link flipped bits in the checksum
    rt.feed(bytes(bad))
    assert conn.receive_data(rt.take_output(), 0.0) == []  # 0xF3 -> resent
    assert conn.stats.retries == 1
    (again,) = conn.data_to_send()
    assert again[1] != frame[1]  # new seq
    rt.feed(again)
    assert conn.receive_data(rt.take_output(), 0.0) == [CallCompleted(op, 0xBA, b"hi")]


def test_a2jmany_short_header_and_bad_target() -> None:
    rt, conn = make_board(), HostConnection()
    short = conn.call(1, b"\x02\x00", 0.0, 1.0)
    beyond = conn.call(1, many_request(230, 0, 0), 0.0, 1.0)
    events = Link(rt, conn).run()
    assert events[0] == CallCompleted(short, 0xFF, b"\x02\x00")  # echoed, as the original
    assert isinstance(events[1], CallFailed) and events[1].code == 0xF0 and events[1].op == beyond


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 3000), st.integers(0, 2**32))
def test_many_read_any_size_any_chunking(size: int, seed: int) -> None:
    blob = random.Random(seed).randbytes(size)
    rt, conn = make_board(blob), HostConnection()
    op = conn.read_many(idx(rt, "blob"), 0.0, 1.0, progress=True)
    events = Link(rt, conn, random.Random(seed)).run(rounds=100)
    done = events[-1]
    assert isinstance(done, TransferCompleted) and done.op == op
    assert done.data == blob and done.status == 0
    chunks = max(1, -(-size // 249))
    assert done.chunks == chunks
    progress = [e for e in events if isinstance(e, TransferProgress)]
    assert [p.done for p in progress] == [249 * k for k in range(1, chunks)]


@settings(max_examples=40, deadline=None)
@given(st.binary(max_size=1500))
def test_many_write_chunks_and_offsets(data: bytes) -> None:
    got: list[tuple[int, bytes, bool]] = []

    def sink(is_write: bool, is_last: bool, offset: int, chunk: bytes) -> tuple[int, bool, bytes]:
        got.append((offset, chunk, is_last))
        return 0, is_last, b""

    rt = make_board()
    rt.add_many_function("sink", sink)
    conn = HostConnection()
    op = conn.write_many(idx(rt, "sink"), data, 0.0, 1.0)
    (done,) = [e for e in Link(rt, conn).run() if isinstance(e, TransferCompleted)]
    assert done.op == op and done.status == 0
    assert b"".join(c for _, c, _ in got) == data
    assert [o for o, _, _ in got] == list(range(0, max(len(data), 1), 249))
    assert [last for _, _, last in got] == [False] * (len(got) - 1) + [True]


def test_many_read_cap() -> None:
    rt, conn = make_board(bytes(5000)), HostConnection()
    conn.read_many(idx(rt, "blob"), 0.0, 1.0, max_bytes=1000)
    events = Link(rt, conn).run()
    assert isinstance(events[-1], CallFailed) and events[-1].reason is FailureReason.LIMIT


def test_many_read_that_never_ends_is_a_protocol_error() -> None:
    rt = make_board()
    rt.add_many_function("stuck", lambda w, last, off, data: (0, False, b""))
    conn = HostConnection()
    conn.read_many(idx(rt, "stuck"), 0.0, 1.0)
    (ev,) = Link(rt, conn).run()
    assert isinstance(ev, CallFailed) and ev.reason is FailureReason.PROTOCOL


def test_many_read_offset_mismatch_is_a_protocol_error() -> None:
    conn = HostConnection()
    conn.read_many(5, 0.0, 1.0)
    conn.data_to_send()
    reply = encode_frame(SOF, 0, 0, many_request(0, 0, 77, b"zz"))
    (ev,) = conn.receive_data(reply, 0.0)
    assert isinstance(ev, CallFailed) and "offset 77" in ev.detail


def test_sifs_in_order_with_gap_counting() -> None:
    conn = HostConnection()
    stream = b"".join(encode_frame(SOS, s, 3, bytes([s])) for s in (250, 251, 254, 255, 1))
    events = conn.receive_data(stream, 0.0)
    assert [(e.seq, e.lost) for e in events if isinstance(e, SifReceived)] == [
        (250, 0),
        (251, 0),
        (254, 2),
        (255, 0),
        (1, 1),
    ]
    assert conn.stats.lost_sifs == 3 and conn.stats.sifs == 5


def test_damaged_frames_become_events() -> None:
    conn = HostConnection()
    bad = bytearray(encode_frame(SOS, 0, 3, b"abc"))
    bad[-2] ^= 1
    (ev,) = conn.receive_data(bytes(bad), 0.0)
    assert isinstance(ev, FrameDamaged) and conn.decoder.stats.bad_checksums == 1


def test_close_fails_everything_pending() -> None:
    conn = HostConnection()
    a = conn.call(4, b"", 0.0, 1.0)
    b = conn.call(4, b"", 0.0, 1.0)
    events = conn.close(FailureReason.BROKEN, "unplugged")
    assert {e.op for e in events if isinstance(e, CallFailed)} == {a, b}
    assert conn.pending() == 0


def test_board_sifs_never_interleave_with_replies_and_replies_go_first() -> None:
    clock = FakeBoardClock()
    rt = BoardRuntime("b", "m", "s", epoch="e", clock=clock)

    class Drv:
        def set_cb(self, fn):  # type: ignore[no-untyped-def]
            self.fn = fn

    d = Drv()
    rt.add_transducer(Transducer("x", 5, "p", "M", 2, "int16_t", -1), d)
    d.fn(0, 10)
    clock.us += 5
    d.fn(0, 11)  # same channel again: the first value is flushed into its own SIF
    d.fn(1, 70000)  # out of int16 range: becomes N/A
    rt.feed(encode_frame(SOF, 7, rt.index["a2jEcho"], b"q"))
    rt.poll()
    conn = HostConnection()
    conn._seq = 7
    conn.call(rt.index["a2jEcho"], b"q", 0.0, 1.0)
    events = conn.receive_data(rt.take_output(), 0.0)
    assert isinstance(events[0], CallCompleted)
    sifs = [e for e in events if isinstance(e, SifReceived)]
    assert [s.seq for s in sifs] == [0, 1]
    import struct

    t0, v0, _t1, v1 = struct.unpack("<QhQh", sifs[0].payload)
    assert (t0, v0, v1) == (1_000_000, 10, -1)
    t0, v0, _t1, v1 = struct.unpack("<QhQh", sifs[1].payload)
    assert (t0, v0, v1) == (1_000_005, 11, -1)


def test_lead_names_the_call_whose_reply_starts_the_bytes_and_only_that() -> None:
    """``lead``: the caller knows when the first byte of a read had arrived; only a reply that
    starts that read (the decoder between frames, a good frame, a call it completes) is the
    lead: the clock probe's t4 is then that moment (host/link.py)."""
    conn = HostConnection()
    op = conn.call(4, b"", 0.0, 1.0)
    (req,) = conn.data_to_send()
    seq = req[1]
    reply = encode_frame(SOF, seq, 0xBA, b"")
    sif = encode_frame(SOS, 0, 3, b"\x00" * 10)
    first = conn.receive_data(reply + sif, 0.1, lead=True)[0]
    assert first == CallCompleted(op, 0xBA, b"", lead=True)
    assert first.lead and first.op == op

    op = conn.call(4, b"", 0.2, 1.0)
    (req,) = conn.data_to_send()
    events = conn.receive_data(sif + encode_frame(SOF, req[1], 0xBA, b""), 0.3, lead=True)
    assert CallCompleted(op, 0xBA, b"") in events and not _leads(events)  # a SIF came first

    op = conn.call(4, b"", 0.4, 1.0)
    (req,) = conn.data_to_send()
    whole = encode_frame(SOF, req[1], 0xBA, b"")
    assert conn.receive_data(whole[:2], 0.5, lead=True) == []  # half a frame ...
    events = conn.receive_data(whole[2:], 0.5, lead=True)
    assert events == [CallCompleted(op, 0xBA, b"")]
    assert not _leads(events)  # ... whose start came in an earlier read

    op = conn.call(4, b"", 0.6, 1.0)
    (req,) = conn.data_to_send()
    foreign = encode_frame(SOF, (req[1] + 7) & 0xFF, 0xBA, b"")
    events = conn.receive_data(foreign + encode_frame(SOF, req[1], 0xBA, b""), 0.7, lead=True)
    assert events == [CallCompleted(op, 0xBA, b"")] and not _leads(events)  # not the head

    op = conn.call(4, b"", 0.8, 1.0)
    (req,) = conn.data_to_send()
    events = conn.receive_data(encode_frame(SOF, req[1], 0xBA, b""), 0.9)
    assert events != []
    assert not _leads(events)  # not asked
