"""How a board session gets its board: a link opened at the board's URL, or a board that dialed
in, handed over by the listener already greeted and described (``intake/listener.py``,
``intake/dialin.py``) into its :class:`Mailbox`.  Either way the session owns the board before
anything can block on it, so ``stop()`` closes it at once."""

from __future__ import annotations

import threading
from collections.abc import Callable

from ...errors import BoardError, MissingLinkError
from ...host.board import Board
from ...host.clock import SYSTEM_CLOCK, Clock
from ...host.reactor import Reactor
from ...logs import ErrorCounts
from ...transport import open_transport
from ..config import BoardSpec

#: how often a waiting session looks at its stop event (s)
_POLL_S = 0.2


class Mailbox:
    """One board that dialed in, waiting for its session: ``put`` (the listener's thread) and
    ``take`` (the session's).  A newer board replaces one not taken yet (that one is closed);
    after ``close()`` (the session stopped) nothing is taken in."""

    def __init__(self) -> None:
        self._board: Board | None = None
        self._closed = False
        self._cond = threading.Condition()

    @property
    def waiting(self) -> Board | None:
        """The board handed over and not taken yet."""
        return self._board

    def put(self, board: Board) -> bool:
        """Hand ``board`` to the session; False when it has stopped (the caller closes it)."""
        with self._cond:
            if self._closed:
                return False
            old, self._board = self._board, board
            self._cond.notify_all()
        if old is not None:
            old.close()
        return True

    def take(self, stop: threading.Event) -> Board:
        """The next board that dials in; ``BoardError`` once ``stop`` is set."""
        with self._cond:
            while self._board is None and not stop.is_set():
                self._cond.wait(_POLL_S)
            board, self._board = self._board, None
        if board is None:
            raise BoardError("dial-in", "stopping")
        return board

    def close(self) -> None:
        with self._cond:
            self._closed = True
            board, self._board = self._board, None
        if board is not None:
            board.close()


class LinkSource:
    def __init__(
        self,
        spec: BoardSpec,
        reactor: Reactor | None,
        faults: ErrorCounts,
        mailbox: Mailbox | None,
        clock: Clock = SYSTEM_CLOCK,
    ) -> None:
        """``faults``: the session's, where the board's reading thread counts what it catches;
        ``mailbox``: where a board that dials in is handed over (else it is opened by URL);
        ``clock``: the daemon's (the reactor's, when there is one), the board's link's too."""
        self.spec, self.reactor, self.faults, self.mailbox = spec, reactor, faults, mailbox
        self.clock = clock

    def open(self, stop: threading.Event, own: Callable[[Board], None]) -> Board:
        """The board with its handshake done; ``own(board)`` as soon as it exists.
        ``BoardError`` once ``stop`` is set."""
        spec = self.spec
        if self.mailbox is not None:
            board = self.mailbox.take(stop)  # (greeted and described by the listener)
            board.link.faults = self.faults  # (what its reading thread catches: ours now)
        else:
            board = Board(open_transport(spec.url), timeout=spec.timeout, reactor=self.reactor,
                          faults=self.faults, clock=self.clock)  # fmt: skip
        board.link.batch_s = spec.batch_ms / 1000  # (when it reads on its own thread)
        own(board)
        if stop.is_set():
            raise BoardError(spec.url, "stopping")
        if self.mailbox is None:
            board.handshake(
                describe=not spec.descriptors,
                deadline=board.clock.monotonic() + spec.handshake_timeout,
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
