"""J2A: the wire protocol between host and sensor boards (pure core: no I/O, time passed in).

- :mod:`.codec` - frames: checksum, escaping, encoder, streaming decoder
- :mod:`.connection` - the host's connection state machine (calls, a2jMany transfers, SIFs)
- :mod:`.blobs` - function mapping and property blobs
- :mod:`.events` - what the connection reports
The board side lives in :mod:`missing_link.board` (MicroPython subset).
"""

from .blobs import BlobError, parse_mapping, parse_properties
from .codec import (
    MAX_ENCODED_FRAME,
    SOF,
    SOS,
    DecoderStats,
    Frame,
    FrameDecoder,
    FrameError,
    FrameErrorKind,
    FrameKind,
    checksum,
    encode_frame,
)
from .connection import ConnectionStats, HostConnection
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

__all__ = [
    "MAX_ENCODED_FRAME",
    "SOF",
    "SOS",
    "BlobError",
    "CallCompleted",
    "CallFailed",
    "ConnectionStats",
    "DecoderStats",
    "Event",
    "FailureReason",
    "Frame",
    "FrameDamaged",
    "FrameDecoder",
    "FrameError",
    "FrameErrorKind",
    "FrameKind",
    "HostConnection",
    "SifReceived",
    "TransferCompleted",
    "TransferProgress",
    "checksum",
    "encode_frame",
    "parse_mapping",
    "parse_properties",
]
