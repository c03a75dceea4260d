"""What a link hands back: a call's result with its stamps, the link's counters, and the clock
exchange a clock call's result makes."""

from __future__ import annotations

import struct
from dataclasses import dataclass

from ..errors import FunctionFailed
from ..timesync.exchange import Exchange


@dataclass(frozen=True)
class CallResult:
    """A reply: the function's return code and payload, and when (ns on the link's clock:
    CLOCK_MONOTONIC unless the board was given another, :mod:`.clock`)."""

    code: int
    payload: bytes
    sent_ns: int = 0  #: just before the request was written (the transport's stamp if later)
    #: when the reply had arrived: the read's ``rx_ns`` (the kernel's stamp, the byte count at
    #: the wake-up), else right after the read that completed it returned
    recv_ns: int = 0
    #: by when the reply's *first* byte had arrived, when known and earlier (the reply headed a
    #: read whose wait returned then: the read's ``first_rx_ns``); 0
    head_ns: int = 0

    @property
    def ok(self) -> bool:
        return self.code == 0


@dataclass(frozen=True)
class LinkStats:
    """A link's counters at one moment: the frame decoder's and the connection's, and what the
    transport counts of its own (a signed link's dropped records), by name."""

    frames: int
    junk_bytes: int
    bad_checksums: int
    bad_escapes: int
    cut_frames: int
    requests: int
    replies: int
    late_replies: int
    foreign_replies: int
    timeouts: int
    board_errors: int
    retries: int
    sifs: int
    sifs_lost: int
    #: SIFs that came while nothing listened for them (before the session's sample path is on:
    #: a board streams from its boot, the host handshakes first); not lost, not published
    sifs_unheard: int
    transport: dict[str, int]


def exchange_of(board: str, name: str, result: CallResult, byte_ns: float) -> Exchange:
    """The clock exchange of an ``a2jClock`` (t2, t3) or ``getTime`` (t2 = t3) reply;
    FunctionFailed (naming ``board`` and ``name``) for a reply that is neither."""
    p = result.payload
    if result.code != 0 or len(p) not in (8, 16):
        raise FunctionFailed(board, name, result.code, p)
    if len(p) == 16:
        t2, t3 = struct.unpack("<QQ", p)
    else:
        (t2,) = struct.unpack("<Q", p)
        t3 = t2
    # On a byte-serial link, the request's bytes before t2 (SOF, seq, op, len, checksum)
    # and the reply's after t3 (SOF, seq, code, len, payload, checksum) are on the wire in
    # every exchange: known delays, not uncertainty.  When the reply headed a read, its
    # first byte (only that one on the wire after t3) had arrived by ``head_ns``: the
    # tighter of the two upper constraints is kept.
    t4, down = result.recv_ns, int((5 + len(p)) * byte_ns)
    if result.head_ns and result.head_ns - int(byte_ns) < t4 - down:
        t4, down = result.head_ns, int(byte_ns)
    return Exchange(result.sent_ns, t2, t3, t4, down, int(5 * byte_ns))
