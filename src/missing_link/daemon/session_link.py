"""How a board session gets its board: a link opened at the board's URL, or a board that dialed
in, handed over by the listener already greeted and described (``listener.py``,
``dialin.py``).  Either way the session owns the board before anything can block on it, so
``stop()`` closes it at once."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from ..errors import BoardError, MissingLinkError
from ..host.board import Board
from ..host.reactor import Reactor
from ..logs import ErrorCounts
from ..transport import open_transport
from .config import BoardSpec
from .listener import Mailbox


class LinkSource:
    def __init__(
        self, spec: BoardSpec, reactor: Reactor | None, faults: ErrorCounts, mailbox: Mailbox | None
    ) -> None:
        """``faults``: the session's, where the board's reading thread counts what it catches;
        ``mailbox``: where a board that dials in is handed over (else it is opened by URL)."""
        self.spec, self.reactor, self.faults, self.mailbox = spec, reactor, faults, mailbox

    def open(self, stop: threading.Event, own: Callable[[Board], None]) -> Board:
        """The board with its handshake done; ``own(board)`` as soon as it exists.
        ``BoardError`` once ``stop`` is set."""
        spec = self.spec
        if self.mailbox is not None:
            board = self.mailbox.take(stop)  # (greeted and described by the listener)
            board.link.faults = self.faults  # (what its reading thread catches: ours now)
        else:
            board = Board(open_transport(spec.url), timeout=spec.timeout, reactor=self.reactor,
                          faults=self.faults)  # fmt: skip
        board.batch_s = spec.batch_ms / 1000  # (when it reads on its own thread)
        own(board)
        if stop.is_set():
            raise BoardError(spec.url, "stopping")
        if self.mailbox is None:
            board.handshake(
                describe=not spec.descriptors, deadline=time.monotonic() + spec.handshake_timeout
            )
        return board


def sif_count(board: Board, timeout: float) -> int | None:
    """The board's count of SIFs sent since boot (``a2jSifCount``), or None."""
    if "a2jSifCount" not in board.index:
        return None
    try:
        payload = board.call_ok("a2jSifCount", timeout=timeout)
    except MissingLinkError:  # (no count: an outage's loss is counted modulo 256 then)
        return None
    return int.from_bytes(payload[:8], "little") if len(payload) >= 8 else None
