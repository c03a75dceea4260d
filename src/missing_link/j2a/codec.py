"""The J2A frame codec (spec Part 1, sections 1.1-1.3): pure, no I/O.

Theory of operation
-------------------
A frame on the wire is ``start | seq | opcode | len | payload | checksum``; ``start`` is raw and
every later byte is escaped (``0x7D, B-1`` for B in {0x12, 0xED, 0x7D}).  Because an escaped byte
is never itself 0x7D, the number of raw bytes a frame body occupies is ``n + number of escapes in
that span`` and can be found with a couple of ``bytes.count`` calls instead of a byte loop.  The
decoder works on whole spans with C-speed bytes methods (find, count, split) and only falls back
to byte-level work for the 3-byte header.

The decoder is a streaming state machine with two states:

* HUNTING: discard bytes up to the next start marker (0x12 SOF or 0xED SOS), counting them as junk.
* IN_FRAME: a start marker was seen at the head of the buffer; wait until the whole frame is
  buffered, then check it.  A raw start marker inside the frame means the frame was cut: count it,
  report it (with the seq if it had arrived, so a board can answer 0xF2), and restart at that
  marker.  A bad escape or checksum is reported and decoding continues after the frame.

Damaged input is data, never an exception: every problem becomes a ``FrameError`` event and a
counter in ``DecoderStats``.
"""

from __future__ import annotations

import re
from dataclasses import asdict, dataclass
from enum import IntEnum
from typing import NamedTuple

SOF = 0x12  #: start of frame: host requests and board replies
SOS = 0xED  #: start of server-initiated frame (SIF), board -> host
ESC = 0x7D
SPECIALS = frozenset((SOF, SOS, ESC))
MAX_PAYLOAD = 255
#: worst case on the wire: start byte + (seq, opcode, len, 255 payload, checksum) all escaped
MAX_ENCODED_FRAME = 1 + 2 * (3 + MAX_PAYLOAD + 1)

# Error codes a board sends as the reply opcode (spec 1.5).
ERR_INDEX = 0xF0
ERR_TIMEOUT = 0xF2
ERR_CHECKSUM = 0xF3
ERR_ESCAPE = 0xF4
ERROR_CODES = {
    ERR_INDEX: "function index out of bounds",
    0xF1: "unused error code 0xF1",
    ERR_TIMEOUT: "timeout or cut frame while receiving",
    ERR_CHECKSUM: "bad checksum",
    ERR_ESCAPE: "bad escape sequence",
}


class FrameKind(IntEnum):
    SOF = SOF
    SOS = SOS


class Frame(NamedTuple):
    """One good frame.  ``kind`` SOF is a request (board side) or reply (host side); SOS a SIF."""

    kind: FrameKind
    seq: int
    opcode: int
    payload: bytes


class FrameErrorKind(IntEnum):
    CHECKSUM = 1
    ESCAPE = 2
    CUT = 3


@dataclass(frozen=True, slots=True)
class FrameError:
    """A damaged frame.  ``seq`` is known when its seq byte had arrived (else None)."""

    kind: FrameErrorKind
    start: FrameKind
    seq: int | None
    detail: str


@dataclass(slots=True)
class DecoderStats:
    frames: int = 0
    junk_bytes: int = 0
    bad_checksums: int = 0
    bad_escapes: int = 0
    cut_frames: int = 0

    def as_dict(self) -> dict[str, int]:
        return asdict(self)


def checksum(seq: int, opcode: int, payload: bytes) -> int:
    """Spec 1.2: XOR of seq, opcode+11, len+97 and every payload byte (unescaped)."""
    return seq ^ ((opcode + 11) & 0xFF) ^ ((len(payload) + 97) & 0xFF) ^ xor_bytes(payload)


# Masks for folding a big integer in halves: XOR of all bytes in O(log n) big-int operations,
# which is much faster in CPython than a Python-level loop over the bytes.
_FOLD_WIDTHS = [8 << k for k in range(12)]  # 8 .. 16384 bits
_FOLD_MASKS = {w: (1 << w) - 1 for w in _FOLD_WIDTHS}
_FOLD_START = [8 << (n - 1).bit_length() if n else 8 for n in range(MAX_PAYLOAD + 1)]


def xor_bytes(data: bytes) -> int:
    """XOR of all bytes of ``data`` (0 for empty data)."""
    n = len(data)
    if n <= 24:  # a plain loop beats big-int setup for short payloads
        x = 0
        for b in data:
            x ^= b
        return x
    x = int.from_bytes(data, "little")
    width = 8 << (n - 1).bit_length()
    while width > 8:
        width >>= 1
        x = (x >> width) ^ (x & _FOLD_MASKS[width])
    return x


def escape(data: bytes) -> bytes:
    """Escape every special byte (spec 1.3).  ESC first, so inserted escapes stay single."""
    if b"\x7d" in data:
        data = data.replace(b"\x7d", b"\x7d\x7c")
    if b"\x12" in data:
        data = data.replace(b"\x12", b"\x7d\x11")
    if b"\xed" in data:
        data = data.replace(b"\xed", b"\x7d\xec")
    return data


def encode_frame(kind: int, seq: int, opcode: int, payload: bytes = b"") -> bytes:
    """Encode one frame for the wire.  Raises ValueError on out-of-range fields (caller's fault)."""
    n = len(payload)
    if n > MAX_PAYLOAD:
        raise ValueError(f"J2A payload is {n} bytes; a frame carries at most {MAX_PAYLOAD}")
    if not (0 <= seq <= 0xFF and 0 <= opcode <= 0xFF):
        raise ValueError(f"seq {seq} and opcode {opcode} must be 0..255")
    if kind != SOF and kind != SOS:
        raise ValueError(f"start marker must be 0x12 or 0xED, not {kind:#x}")
    body = bytes((seq, opcode, n)) + payload
    body += bytes((checksum(seq, opcode, payload),))
    return bytes((kind,)) + escape(body)


_MARKERS = re.compile(b"[\x12\xed]")
_new_frame = tuple.__new__  # Frame(...) without NamedTuple's Python-level __new__ (hot path)


def _find_marker(buf: bytes, start: int, stop: int) -> int:
    """Index of the first raw start marker in buf[start:stop], or -1 (two C-speed finds)."""
    a = buf.find(b"\x12", start, stop)
    b = buf.find(b"\xed", start, stop)
    if a < 0:
        return b
    return a if b < 0 or a < b else b


_KIND = {SOF: FrameKind.SOF, SOS: FrameKind.SOS}
_UNESCAPE_OK = frozenset((SOF - 1, SOS - 1, ESC - 1))  # bytes allowed after ESC
_UNESCAPED = {bytes((b,)): bytes((b + 1,)) for b in _UNESCAPE_OK}


def _unescape(buf: bytes, p: int, stop: int) -> bytes | None:
    """The escaped span ``buf[p:stop]`` unescaped, or None when an escape is not one of the
    three (the bytes after ESC are split off and looked up: no byte loop)."""
    parts = buf[p:stop].split(b"\x7d")
    for i in range(1, len(parts)):
        part = parts[i]
        r = _UNESCAPED.get(part[:1])
        if r is None:
            return None
        parts[i] = r + part[1:]
    return b"".join(parts)


class FrameDecoder:
    """Streaming J2A decoder.  ``feed(data)`` returns good frames and errors in arrival order."""

    __slots__ = ("_buf", "stats")

    def __init__(self, stats: DecoderStats | None = None) -> None:
        self._buf = b""
        #: its counters: its own, or a larger struct it counts into (a connection's: every
        #: counter of a link in one place)
        self.stats = DecoderStats() if stats is None else stats

    @property
    def buffered(self) -> int:
        """Bytes held that belong to an unfinished frame."""
        return len(self._buf)

    def in_frame(self) -> bool:
        """True while a started frame is waiting for more bytes (for inter-byte timeouts)."""
        return bool(self._buf)

    def abort_frame(self) -> FrameError | None:
        """Drop a half-received frame (e.g. after an inter-byte timeout)."""
        if not self._buf:
            return None
        seq = self._peek_seq(self._buf)
        start = _KIND[self._buf[0]]
        self._buf = b""
        self.stats.cut_frames += 1
        return FrameError(FrameErrorKind.CUT, start, seq, "frame abandoned after silence")

    @staticmethod
    def _peek_seq(buf: bytes) -> int | None:
        if len(buf) < 2:
            return None
        b = buf[1]
        if b != ESC:
            return b
        return buf[2] + 1 if len(buf) >= 3 else None

    def _report(
        self,
        out: list[Frame | FrameError],
        kind: FrameErrorKind,
        first: int,
        seq: int | None,
        detail: str,
    ) -> None:
        """Count one damaged frame and report it (the rare path, out of ``feed``'s loop)."""
        stats = self.stats
        if kind is FrameErrorKind.CUT:
            stats.cut_frames += 1
        elif kind is FrameErrorKind.ESCAPE:
            stats.bad_escapes += 1
        else:
            stats.bad_checksums += 1
        out.append(FrameError(kind, _KIND[first], seq, detail))

    def _slow_header(
        self, buf: bytes, pos: int, end: int, first: int, out: list[Frame | FrameError]
    ) -> tuple[int, int, int, int] | int | None:
        """Header with escapes, cut or incomplete: (seq, opcode, len, body start), or the
        position to resume at after a reported error, or None when more bytes are needed."""
        hdr = [0, 0, 0]
        p = pos + 1
        k = 0
        while k < 3:
            if p >= end:
                return None
            b = buf[p]
            # A raw start marker (alone, or right after an escape) means the frame was cut.
            cut_at = p if b in (SOF, SOS) else -1
            if b == ESC:
                if p + 1 >= end:
                    return None
                if buf[p + 1] in (SOF, SOS):
                    cut_at = p + 1
            seq = hdr[0] if k > 0 else None
            if cut_at >= 0:
                self._report(
                    out, FrameErrorKind.CUT, first, seq, "start marker inside frame header"
                )
                return cut_at
            if b == ESC:
                b2 = buf[p + 1]
                p += 2
                if b2 not in _UNESCAPE_OK:
                    self._report(
                        out, FrameErrorKind.ESCAPE, first, seq, f"escape 7d {b2:02x} in header"
                    )
                    return p
                hdr[k] = b2 + 1
            else:
                hdr[k] = b
                p += 1
            k += 1
        return hdr[0], hdr[1], hdr[2], p

    def _hunt(self, buf: bytes, pos: int, end: int) -> int:
        """Skip to the next start marker (or the end), counting what was skipped as junk."""
        m = _MARKERS.search(buf, pos)
        at = end if m is None else m.start()
        self.stats.junk_bytes += at - pos
        return at

    @staticmethod
    def _span_tail(buf: bytes, p: int, stop: int, end: int) -> int | None:
        """A body span that runs past the bytes here, or ends in an escape: the stop to check
        for a start marker (the frame was cut), or None when more bytes are needed."""
        if stop > end:  # incomplete, unless a start marker already shows the frame was cut
            return end if _find_marker(buf, p, end) >= 0 else None
        # The span ends in an escape whose partner is not here yet: one more byte needed.
        return stop + 1 if stop < end else None

    def feed(self, data: bytes) -> list[Frame | FrameError]:
        """Every good frame and error in ``data`` (after what was held), in arrival order.  The
        common frame stays in this loop; damage, escaped headers and cut frames go to helpers."""
        out: list[Frame | FrameError] = []
        buf = self._buf + data if self._buf else bytes(data)
        good = 0
        pos = 0
        end = len(buf)
        while pos < end:
            first = buf[pos]
            if first != SOF and first != SOS:
                pos = self._hunt(buf, pos, end)
                if pos == end:
                    break
                first = buf[pos]
            # --- header: seq, opcode, len; fast path when none of them is escaped ---
            if (
                pos + 4 <= end
                and (seq := buf[pos + 1]) not in SPECIALS
                and (opcode := buf[pos + 2]) not in SPECIALS
                and (n := buf[pos + 3]) not in SPECIALS
            ):
                p = pos + 4
            else:
                got = self._slow_header(buf, pos, end, first, out)
                if got is None:
                    break  # need more bytes
                if isinstance(got, int):
                    pos = got  # damaged header reported; continue from here
                    continue
                seq, opcode, n, p = got
            # --- body: n payload bytes + checksum; raw span = n + 1 + escapes inside it ---
            need = n + 1
            stop = p + need
            esc = buf.count(b"\x7d", p, stop)
            while p + need + esc != stop:  # the escapes found lengthen the span: count again
                stop = p + need + esc
                esc = buf.count(b"\x7d", p, stop)
            if stop > end or buf[stop - 1] == ESC:
                tail = self._span_tail(buf, p, stop, end)
                if tail is None:
                    break  # need more bytes
                stop = tail
            if buf.find(b"\x12", p, stop) >= 0 or buf.find(b"\xed", p, stop) >= 0:
                self._report(out, FrameErrorKind.CUT, first, seq, "start marker inside frame")
                pos = _find_marker(buf, p, stop)
                continue
            if esc:
                body = _unescape(buf, p, stop)
                if body is None or len(body) != need:  # (misaligned: a lone escape at the end)
                    why = "bad escape in payload" if body is None else "escape misaligned frame"
                    self._report(out, FrameErrorKind.ESCAPE, first, seq, why)
                    pos = stop
                    continue
                payload = body[:n]
                got_sum = body[n]
            else:
                payload = buf[p : p + n]
                got_sum = buf[p + n]
            if n > 24:  # xor_bytes inlined: this is the hot path
                x = int.from_bytes(payload, "little")
                width = _FOLD_START[n]
                while width > 8:
                    width >>= 1
                    x = (x >> width) ^ (x & _FOLD_MASKS[width])
            else:
                x = 0
                for c in payload:
                    x ^= c
            want = seq ^ ((opcode + 11) & 0xFF) ^ ((n + 97) & 0xFF) ^ x
            pos = stop
            if got_sum != want:
                detail = f"checksum {got_sum:#04x}, expected {want:#04x}"
                self._report(out, FrameErrorKind.CHECKSUM, first, seq, detail)
                continue
            good += 1
            out.append(_new_frame(Frame, (_KIND[first], seq, opcode, payload)))
        self.stats.frames += good
        self._buf = buf[pos:] if pos < end else b""
        return out
