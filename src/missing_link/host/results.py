"""What a link hands back: a call's result with its stamps (``settle``: a request's future from
the connection's event), the link's counters, and the clock exchange a clock call's result
makes."""

from __future__ import annotations

import struct
from collections.abc import Mapping
from concurrent.futures import Future
from dataclasses import dataclass, field, fields
from typing import Any, NamedTuple

from ..errors import BoardError, CallError, CallTimeout, FunctionFailed, LinkLost
from ..j2a import CallCompleted, CallFailed, ConnectionStats, FailureReason, TransferCompleted
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


@dataclass(slots=True)
class LinkStats(ConnectionStats):
    """A link's counters at one moment: its connection's (the frame decoder's and the
    connection's own, j2a's ConnectionStats) and the link's, and what the transport counts of
    its own (a signed link's dropped records), by name.  A snapshot (``BoardLink.stats``: the
    link counts on in its own struct).  Counters of several links add up (``a + b``: a
    session's over every link it had)."""

    #: SIFs that came while nothing listened for them (before the session's sample path is on:
    #: a board streams from its boot, the host handshakes first); not lost, not published
    unheard_sifs: int = 0
    transport: Mapping[str, int] = field(default_factory=dict)

    def __add__(self, other: LinkStats) -> LinkStats:
        summed = dict(self.transport)
        for key, n in other.transport.items():
            summed[key] = summed.get(key, 0) + n
        counts = {f: getattr(self, f) + getattr(other, f) for f in _COUNTS}
        return LinkStats(**counts, transport=summed)


_COUNTS = tuple(f.name for f in fields(LinkStats) if f.name != "transport")


class Asked(NamedTuple):
    """What a request was: the board and the function errors name, a many-write (its status is
    the result), and when it was written (ns)."""

    board: str
    label: str
    write: bool
    sent_ns: int


def settle(
    fut: Future[Any],
    ev: CallCompleted | CallFailed | TransferCompleted,
    asked: Asked,
    now_ns: int,
    head_ns: int = 0,
) -> None:
    """Resolve a request's future from the event that ended it: a reply (its stamps), a
    transfer's data or status, or the error that says why there is none."""
    if isinstance(ev, CallCompleted):
        fut.set_result(CallResult(ev.code, ev.payload, asked.sent_ns, now_ns, head_ns))
    elif isinstance(ev, TransferCompleted):
        if asked.write:
            fut.set_result(ev.status)  # a write reports the function's status
        elif ev.status == 0:
            fut.set_result(ev.data)
        else:
            fut.set_exception(FunctionFailed(asked.board, asked.label, ev.status, ev.data))
    else:
        fut.set_exception(failure(asked.board, asked.label, ev))


def failure(board: str, label: str, ev: CallFailed) -> BoardError:
    """The error a failed call raises, by why it failed."""
    if ev.reason is FailureReason.TIMEOUT:
        return CallTimeout(board, label, ev.detail)
    if ev.reason in (FailureReason.CLOSED, FailureReason.BROKEN):
        return LinkLost(board, label, ev.detail, ev.reason is FailureReason.BROKEN)
    return CallError(board, label, ev.detail, ev.code)


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
