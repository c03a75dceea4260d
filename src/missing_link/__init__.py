"""missing-link: sensor boards on a J2A backbone; every transducer a typed, time-stamped topic.

Two lines give an application a board::

    import missing_link
    board = missing_link.open_board("serial:///dev/ttyACM0")
"""

from .client import AsyncBoard, Board, CallResult, open_board, open_board_async
from .descriptors import Transducer, parse_transds
from .errors import (
    BadURL,
    BoardError,
    CallError,
    CallTimeout,
    DescriptorError,
    FunctionFailed,
    LinkLost,
    MissingLinkError,
    TransportBroken,
    TransportClosed,
    TransportError,
    UnknownFunction,
)
from .samples import Sample, SampleDecoder
from .transport import Transport, open_transport

__version__ = "0.1.0"

__all__ = [
    "AsyncBoard",
    "BadURL",
    "Board",
    "BoardError",
    "CallError",
    "CallResult",
    "CallTimeout",
    "DescriptorError",
    "FunctionFailed",
    "LinkLost",
    "MissingLinkError",
    "Sample",
    "SampleDecoder",
    "Transducer",
    "Transport",
    "TransportBroken",
    "TransportClosed",
    "TransportError",
    "UnknownFunction",
    "__version__",
    "open_board",
    "open_board_async",
    "open_transport",
    "parse_transds",
]
