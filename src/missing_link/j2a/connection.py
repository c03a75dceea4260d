"""The host side of a J2A connection, sans-I/O: bytes and ``now`` in, events and frames out.

Theory of operation
-------------------
The caller starts *operations*: a plain ``call`` (one request, one reply) or an a2jMany
``read_many``/``write_many`` transfer (a chain of chunk requests to a2jMany, index 1).  Each gets an
op id.  Operations wait in a FIFO queue; at most ``window`` requests are in flight (default 1: the
original board processes one frame at a time and answers before reading the next).  A request is
given the next 8-bit seq when it is sent, so the seq advances on every request, and replies are
matched by seq:

* a reply whose seq matches an in-flight request completes that step;
* a reply whose seq belongs to a request that already timed out is *late*: discarded, counted;
* any other reply is *foreign*: discarded, counted.  Neither ever reaches the next caller.

A reply opcode 0xF0..0xF4 is an error frame.  0xF2/0xF3/0xF4 mean the request did not arrive
intact, so the function did not run and the request is sent again (fresh seq) up to ``retries``
times; 0xF0 (no such function) fails at once.  A timeout is never retried: the function may have
run.  Timers: every in-flight request has a deadline (``now + timeout``); ``get_timer()`` returns
the earliest, ``handle_timer(now)`` fails the expired ones.

A transfer moves one chunk at a time.  Reads ask at increasing offsets; every reply must echo the
offset and carry data unless it is the last; the one with isLast ends the transfer.  Writes send
chunks of up to 249 bytes, the last with isLast.  A nonzero return value from the target function
ends the transfer with that status.  Transfers are capped in bytes and chunks, and may be given an
overall deadline (``deadline``, in ``now`` units) besides the per-chunk timeout: a board that
streams chunks for ever without isLast cannot hold a caller.  A transfer that makes no progress
fails at once: a chunk without data and without isLast.  The 2014 firmware's a2jMany used only
the low byte of the offset, so it answers an offset past 255 with the data of ``offset & 0xFF``
and never sends the last chunk of a blob over 504 bytes (whatever the data: a blob that repeats
every 256 bytes looks right and still never ends).  A transfer with a board known to be the
2014 firmware (``original``) therefore fails the moment it would move a chunk past offset 255
-- after two chunks, 498 bytes -- naming the bug, instead of spinning until its deadline.

SIFs (0xED frames) are delivered in arrival order; the gap between a SIF's seq and the previous
one's is reported as lost SIFs.  Damaged frames become ``FrameDamaged`` events and counters.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

from .blobs import FLAG_LAST, FLAG_WRITE, MANY_CHUNK, MANY_HEADER
from .codec import (
    ERROR_CODES,
    SOF,
    SOS,
    DecoderStats,
    Frame,
    FrameDecoder,
    FrameError,
    encode_frame,
)
from .events import (
    CallCompleted,
    CallFailed,
    Event,
    FailureReason,
    FrameDamaged,
    SifReceived,
    TransferCompleted,
    TransferProgress,
)

A2J_MANY = 1
#: the spec's cap on a2jMany chunks: 4 GiB in 249-byte chunks
MAX_MANY_CHUNKS = (4 << 30) // MANY_CHUNK
DEFAULT_MAX_TRANSFER = 64 << 20
#: the 2014 firmware's a2jMany passes only the offset's low byte: no chunk starts past this,
#: so the largest blob it can move is two whole chunks
ORIGINAL_MAX_OFFSET = 255
ORIGINAL_MAX_BLOB = 2 * MANY_CHUNK
_RETRYABLE = frozenset((0xF2, 0xF3, 0xF4))
_SOF_BYTE = bytes((SOF,))
_LATE_MEMORY = 64


@dataclass(slots=True)
class ConnectionStats(DecoderStats):
    """A connection's counters: its frame decoder's (the decoder counts into this struct) and
    its own, one struct under one spelling (host/results.py's LinkStats adds the link's)."""

    requests: int = 0
    replies: int = 0
    late_replies: int = 0
    foreign_replies: int = 0
    timeouts: int = 0
    board_errors: int = 0
    retries: int = 0
    sifs: int = 0
    lost_sifs: int = 0


@dataclass
class _Op:
    op: int
    timeout: float
    # plain call
    index: int = 0
    payload: bytes = b""
    # transfer
    many: bool = False
    target: int = 0
    write: bool = False
    data: bytes = b""
    offset: int = 0
    chunks: int = 0
    max_bytes: int = DEFAULT_MAX_TRANSFER
    progress: bool = False
    received: bytearray = field(default_factory=bytearray)
    deadline_total: float = math.inf  #: the whole transfer must end by then
    total_s: float = 0.0  #: for the error message
    original: bool = False  #: the board is the 2014 firmware (its a2jMany offset bug)
    retries_left: int = 0
    # in flight
    seq: int = -1
    deadline: float = 0.0

    def next_request(self) -> tuple[int, bytes]:
        """(opcode, payload) of the next frame this operation sends."""
        if not self.many:
            return self.index, self.payload
        if self.write:
            chunk = self.data[self.offset : self.offset + MANY_CHUNK]
            last = self.offset + len(chunk) >= len(self.data)
            flags = FLAG_WRITE | (FLAG_LAST if last else 0)
            return A2J_MANY, MANY_HEADER.pack(self.target, flags, self.offset) + chunk
        return A2J_MANY, MANY_HEADER.pack(self.target, 0, self.offset)


class HostConnection:
    def __init__(self, *, window: int = 1, retries: int = 2) -> None:
        if not 1 <= window <= 128:
            raise ValueError("window must be 1..128 requests in flight")
        self.window = window
        self.retries = retries
        self.stats = ConnectionStats()
        self.decoder = FrameDecoder(self.stats)
        self._next_op = 1
        self._seq = 0
        self._queue: deque[_Op] = deque()
        self._in_flight: dict[int, _Op] = {}
        self._timed_out: deque[int] = deque(maxlen=_LATE_MEMORY)
        self._out: list[bytes] = []
        self._sif_expected: int | None = None
        self._closed: FailureReason | None = None

    # ---- starting operations ------------------------------------------------------------
    def call(self, index: int, payload: bytes, now: float, timeout: float) -> int:
        if not 0 <= index <= 0xEF:
            raise ValueError(f"function index {index} outside 0..239")
        if len(payload) > 255:
            raise ValueError(f"payload of {len(payload)} bytes; use write_many above 255")
        return self._start(_Op(op=0, timeout=timeout, index=index, payload=bytes(payload)), now)

    def read_many(
        self,
        target: int,
        now: float,
        timeout: float,
        *,
        max_bytes: int = DEFAULT_MAX_TRANSFER,
        progress: bool = False,
        deadline: float | None = None,
        original: bool = False,
    ) -> int:
        """Read a many-function's blob; ``deadline`` (``now`` units) bounds the whole transfer.
        ``original``: the board is the 2014 firmware, which cannot serve a chunk past offset 255
        (see the theory of operation): such a read fails at once, naming the bug."""
        op = _Op(op=0, timeout=timeout, many=True, target=target, max_bytes=max_bytes)
        op.progress = progress
        op.original = original
        if deadline is not None:
            op.deadline_total = deadline
            op.total_s = deadline - now
        return self._start(op, now)

    def write_many(
        self,
        target: int,
        data: bytes,
        now: float,
        timeout: float,
        *,
        progress: bool = False,
        original: bool = False,
    ) -> int:
        if len(data) > MAX_MANY_CHUNKS * MANY_CHUNK:
            raise ValueError(f"{len(data)} bytes exceed the a2jMany limit")
        if original and len(data) > ORIGINAL_MAX_BLOB:
            raise ValueError(
                f"{len(data)} bytes cannot be written to the 2014 firmware: its a2jMany offset "
                f"bug (it uses only the offset's low byte) limits a blob to {ORIGINAL_MAX_BLOB}"
            )
        op = _Op(op=0, timeout=timeout, many=True, target=target, write=True, data=bytes(data))
        op.progress = progress
        op.original = original
        return self._start(op, now)

    def _start(self, op: _Op, now: float) -> int:
        if self._closed is not None:
            raise RuntimeError(f"connection is {self._closed.value}; no new calls")
        if op.timeout <= 0:
            raise ValueError("timeout must be positive")
        op.op = self._next_op
        op.retries_left = self.retries
        self._next_op += 1
        self._queue.append(op)
        self._pump(now)
        return op.op

    def expect_sif_seq(self, seq: int) -> None:
        """Count the gap to the next SIF from ``seq`` (a link re-opened to the same board boot:
        the SIFs it sent meanwhile are lost, and counted, modulo 256)."""
        self._sif_expected = seq & 0xFF

    def pending(self) -> int:
        return len(self._queue) + len(self._in_flight)

    # ---- output and timers --------------------------------------------------------------
    def data_to_send(self) -> list[bytes]:
        """Encoded frames to write, one per element (USB sends one OUT transfer per frame)."""
        out, self._out = self._out, []
        return out

    def get_timer(self) -> float | None:
        if not self._in_flight:
            return None
        return min(op.deadline for op in self._in_flight.values())

    def handle_timer(self, now: float) -> list[Event]:
        events: list[Event] = []
        for seq, op in list(self._in_flight.items()):
            if now >= op.deadline:
                del self._in_flight[seq]
                self._timed_out.append(seq)
                if now >= op.deadline_total:
                    events.append(
                        CallFailed(
                            op.op,
                            FailureReason.LIMIT,
                            None,
                            f"transfer not finished within {op.total_s:.1f} s "
                            f"({op.offset} bytes in {op.chunks} chunks, no isLast yet)",
                        )
                    )
                    continue
                self.stats.timeouts += 1
                what = f"chunk at offset {op.offset}" if op.many else "reply"
                events.append(
                    CallFailed(
                        op.op,
                        FailureReason.TIMEOUT,
                        None,
                        f"no {what} within {op.timeout * 1000:.0f} ms",
                    )
                )
        if events:
            self._pump(now)
        return events

    def close(self, reason: FailureReason = FailureReason.CLOSED, detail: str = "") -> list[Event]:
        """Fail every pending operation (the link is gone or we are shutting down)."""
        if self._closed is None:
            self._closed = reason
        text = detail or f"connection {reason.value}"
        events: list[Event] = [
            CallFailed(op.op, reason, None, text)
            for op in [*self._in_flight.values(), *self._queue]
        ]
        self._in_flight.clear()
        self._queue.clear()
        return events

    def _pump(self, now: float) -> None:
        while self._queue and len(self._in_flight) < self.window:
            self._send(self._queue.popleft(), now)

    def _send(self, op: _Op, now: float) -> None:
        seq = self._seq
        self._seq = (seq + 1) & 0xFF
        while seq in self._in_flight:  # only possible with a window near 256
            seq = self._seq
            self._seq = (seq + 1) & 0xFF
        opcode, payload = op.next_request()
        op.seq = seq
        op.deadline = min(now + op.timeout, op.deadline_total)
        self._in_flight[seq] = op
        self.stats.requests += 1
        self._out.append(encode_frame(SOF, seq, opcode, payload))

    # ---- input --------------------------------------------------------------------------
    def receive_data(self, data: bytes, now: float, *, lead: bool = False) -> list[Event]:
        """Bytes from the board: events in arrival order.  ``lead``: the caller knows a moment
        by which the first of ``data`` had arrived (a clock reply's tighter t4); the reply whose
        frame starts at ``data[0]``, if any, then says so (``CallCompleted.lead``)."""
        events: list[Event] = []
        head = lead and data[:1] == _SOF_BYTE and not self.decoder.in_frame()
        items = self.decoder.feed(data)
        if head and items and not isinstance(items[0], FrameError) and items[0].kind == SOF:
            self._on_reply(items[0], now, events)
            if len(events) == 1 and type(events[0]) is CallCompleted:
                events[0] = events[0]._replace(lead=True)
            items = items[1:]
        for item in items:
            if isinstance(item, FrameError):
                events.append(FrameDamaged(item))
            elif item.kind == SOS:
                events.append(self._on_sif(item))
            else:
                self._on_reply(item, now, events)
        if self._queue:
            self._pump(now)
        return events

    def _on_sif(self, frame: Frame) -> SifReceived:
        self.stats.sifs += 1
        lost = 0
        if self._sif_expected is not None:
            lost = (frame.seq - self._sif_expected) & 0xFF
            self.stats.lost_sifs += lost
        self._sif_expected = (frame.seq + 1) & 0xFF
        return SifReceived(frame.opcode, frame.seq, frame.payload, lost)

    def _on_reply(self, frame: Frame, now: float, events: list[Event]) -> None:
        op = self._in_flight.pop(frame.seq, None)
        if op is None:
            if frame.seq in self._timed_out:
                self.stats.late_replies += 1
            else:
                self.stats.foreign_replies += 1
            return
        self.stats.replies += 1
        code = frame.opcode
        if code in ERROR_CODES:
            self.stats.board_errors += 1
            if code in _RETRYABLE and op.retries_left > 0:
                op.retries_left -= 1
                self.stats.retries += 1
                self._queue.appendleft(op)
                return
            diag = int.from_bytes(frame.payload[:2], "big") if len(frame.payload) >= 2 else None
            events.append(
                CallFailed(
                    op.op,
                    FailureReason.BOARD_ERROR,
                    code,
                    f"board error {code:#04x} ({ERROR_CODES[code]})"
                    + (f", diagnostic {diag}" if diag is not None else ""),
                )
            )
            return
        if not op.many:
            events.append(CallCompleted(op.op, code, frame.payload))
            return
        self._on_chunk(op, frame, events)

    def _on_chunk(self, op: _Op, frame: Frame, events: list[Event]) -> None:
        """One a2jMany reply: the transfer's end, the next chunk queued, or why it failed."""
        p = frame.payload
        if frame.opcode != 0 or len(p) < 6:
            what = f"a2jMany answered {frame.opcode:#04x} with {len(p)} bytes"
            events.append(_failed(op, what, code=frame.opcode))
            return
        status, flags, offset = MANY_HEADER.unpack_from(p)
        chunk = p[6:]
        if offset != op.offset:
            events.append(_failed(op, f"a2jMany reply for offset {offset}, expected {op.offset}"))
            return
        op.chunks += 1
        last = bool(flags & FLAG_LAST)
        if op.write:
            sent = min(MANY_CHUNK, len(op.data) - op.offset)
            op.offset += sent
            done = op.offset >= len(op.data)
            last = last or done
        else:
            op.received += chunk
            op.offset += len(chunk)
            if not chunk and not last:
                what = f"a2jMany read returned no data at offset {offset} without isLast"
                events.append(_failed(op, what))
                return
            if op.offset > op.max_bytes or op.chunks >= MAX_MANY_CHUNKS:
                what = f"transfer passed the cap of {op.max_bytes} bytes"
                events.append(_failed(op, what, FailureReason.LIMIT))
                return
        if status != 0 or last:
            data = bytes(op.received) if not op.write else b""
            events.append(TransferCompleted(op.op, status, data, op.chunks))
            return
        if op.original and op.offset > ORIGINAL_MAX_OFFSET:
            what = (
                f"a2jMany {'write' if op.write else 'read'} past offset 255 (next chunk at "
                f"{op.offset}) from the 2014 firmware: its a2jMany offset bug (it uses only "
                f"the offset's low byte) would give the data of offset {op.offset & 0xFF} "
                "and never the last chunk, so a blob over 498 bytes cannot be moved"
            )
            events.append(_failed(op, what))
            return
        if op.progress:
            total = len(op.data) if op.write else None
            events.append(TransferProgress(op.op, op.offset, total, op.chunks))
        op.retries_left = self.retries
        self._queue.appendleft(op)


def _failed(
    op: _Op,
    detail: str,
    reason: FailureReason = FailureReason.PROTOCOL,
    code: int | None = None,
) -> CallFailed:
    """A transfer that cannot go on: the board broke the a2jMany rules, or a cap was passed."""
    return CallFailed(op.op, reason, code, detail)
