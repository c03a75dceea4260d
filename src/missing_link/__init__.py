"""missing-link: sensor boards on a J2A backbone; every transducer a typed, time-stamped topic.

Two lines give an application its boards, every transducer a topic::

    import missing_link
    robot = missing_link.connect("serial:///dev/ttyACM0")
    robot.subscribe("/thesis/dist_ir", print)

or one board, its functions by name: ``board = missing_link.open_board(url)``.

The house, from the ground up (each room imports only from rooms below it):

- core: :mod:`.errors`, :mod:`.text`, :mod:`.descriptors`, :mod:`.j2a` (the wire),
  :mod:`.timesync` (clock sync), :mod:`.board` (the board runtime, also on MicroPython);
- :mod:`.transport` (bytes by URL), :mod:`.ros` (ROS vocabulary without I/O);
- :mod:`.host` (one board from the host: link, reactor, ``Board``, ``AsyncBoard``),
  :mod:`.topics` (what the daemon hands publishers);
- :mod:`.publishers` (bus, MCAP, Zenoh, ROS 2, ROS 1, Foxglove, console);
- :mod:`.daemon` (many boards -> topics);
- :mod:`.virtual` (simulated boards, links, clocks), :mod:`.deploy` (board files, flashing);
- :mod:`.cli` (the ``missing-link`` command).

Each public name is imported on first use, so ``import missing_link`` costs next to nothing and
a one-off ``missing-link call`` loads only what it uses.
"""

from __future__ import annotations

import logging

# A library says nothing on stderr unless the application configures logging (the CLI does).
logging.getLogger(__name__).addHandler(logging.NullHandler())

# (not typing's: importing typing costs a one-off command milliseconds; type checkers take any
# name TYPE_CHECKING as true)
TYPE_CHECKING = False
if TYPE_CHECKING:  # (for type checkers and readers; at run time see __getattr__)
    from typing import Any

    from .daemon.service import Daemon, connect
    from .descriptors import Transducer, parse_transds
    from .errors import (
        BadURL,
        BoardError,
        CallError,
        CallTimeout,
        ConfigError,
        DescriptorError,
        FunctionFailed,
        LinkLost,
        MissingLinkError,
        TransportBroken,
        TransportClosed,
        TransportError,
        UnknownFunction,
    )
    from .host.aio import AsyncBoard, open_board_async
    from .host.board import Board, open_board
    from .host.board_log import LogLine
    from .host.link import CallResult
    from .host.samples import Sample, SampleDecoder
    from .transport.base import Transport
    from .transport.registry import open_transport
    from .version import __version__

#: public name -> the module that defines it
_WHERE = {
    "__version__": "version",
    "AsyncBoard": "host.aio",
    "open_board_async": "host.aio",
    "Board": "host.board",
    "open_board": "host.board",
    "LogLine": "host.board_log",
    "CallResult": "host.link",
    "Sample": "host.samples",
    "SampleDecoder": "host.samples",
    "Daemon": "daemon.service",
    "connect": "daemon.service",
    "Transducer": "descriptors",
    "parse_transds": "descriptors",
    "Transport": "transport.base",
    "open_transport": "transport.registry",
    **{
        name: "errors"
        for name in (
            "BadURL",
            "BoardError",
            "CallError",
            "CallTimeout",
            "ConfigError",
            "DescriptorError",
            "FunctionFailed",
            "LinkLost",
            "MissingLinkError",
            "TransportBroken",
            "TransportClosed",
            "TransportError",
            "UnknownFunction",
        )
    },
}

__all__ = [
    "AsyncBoard",
    "BadURL",
    "Board",
    "BoardError",
    "CallError",
    "CallResult",
    "CallTimeout",
    "ConfigError",
    "Daemon",
    "DescriptorError",
    "FunctionFailed",
    "LinkLost",
    "LogLine",
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


def __getattr__(name: str) -> Any:
    module = _WHERE.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value  # once: later look-ups are plain attribute reads
    return value


def __dir__() -> list[str]:
    return __all__
