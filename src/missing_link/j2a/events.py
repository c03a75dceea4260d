"""Events the host connection hands to its caller.  Small, immutable, cheap to create."""

from __future__ import annotations

from enum import Enum
from typing import NamedTuple

from .codec import FrameError


class FailureReason(Enum):
    TIMEOUT = "timeout"  #: no reply within the call's timeout (the function may have run)
    BOARD_ERROR = "board error"  #: the board answered with an error frame (0xF0..0xF4)
    PROTOCOL = "protocol"  #: the reply broke the protocol (e.g. an a2jMany offset mismatch)
    LIMIT = "limit"  #: a transfer grew past the configured cap
    CLOSED = "closed"  #: the connection was closed locally before the reply came
    BROKEN = "broken"  #: the link failed before the reply came


class CallCompleted(NamedTuple):
    """A plain call got its reply: ``code`` is the function's return value."""

    op: int
    code: int
    payload: bytes
    #: its frame began the bytes of a ``receive_data(lead=True)``: the moment the caller knows
    #: those arrived by is when this reply did (a clock reply's tighter t4: host/link.py)
    lead: bool = False


class CallFailed(NamedTuple):
    """A call or transfer ended without a usable reply."""

    op: int
    reason: FailureReason
    code: int | None  #: board error code for BOARD_ERROR
    detail: str


class TransferProgress(NamedTuple):
    op: int
    done: int  #: bytes moved so far
    total: int | None  #: known for writes, None for reads
    chunks: int


class TransferCompleted(NamedTuple):
    """An a2jMany transfer ended: ``status`` is the target function's last return value."""

    op: int
    status: int
    data: bytes  #: read data (empty for writes)
    chunks: int


class SifReceived(NamedTuple):
    """A server-initiated frame.  ``lost``: SIFs missed before this one, from the SIF seq."""

    cmd: int
    seq: int
    payload: bytes
    lost: int


class FrameDamaged(NamedTuple):
    """Damaged input from the link (also counted in the decoder stats)."""

    error: FrameError


Event = (
    CallCompleted | CallFailed | TransferProgress | TransferCompleted | SifReceived | FrameDamaged
)
