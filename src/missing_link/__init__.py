"""missing-link: sensor boards on a J2A backbone; every transducer a typed, time-stamped topic.

Two lines give an application its boards, every transducer a topic::

    import missing_link
    robot = missing_link.connect("serial:///dev/ttyACM0")
    robot.subscribe("/thesis/dist_ir", print)

or one board, its functions by name: ``board = missing_link.open_board(url)``.
"""

from .client import AsyncBoard, Board, CallResult, open_board, open_board_async
from .daemon import Daemon, connect
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
    "Daemon",
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
    "connect",
    "open_board",
    "open_board_async",
    "open_transport",
    "parse_transds",
]
