"""The last word to a board: once it has been told goodbye, nothing more reaches it but the close.

``a2jGoodbye`` makes every actuator of the board safe and drops its timed calls (board/
failsafe.py): a call that reached the board after it would move it again, with no host left
to watch (a timed command sent from the clock map's answer, a ``Daemon.call`` or
``trigger_at`` while the session waits for the goodbye's answer).  So every call of a command
path goes through :meth:`Farewell.call_future`, which refuses (``SaidGoodbye``) once
:meth:`Farewell.say` has sent the goodbye on that link; both hold one lock, so a call either
went out before the goodbye (which then drops it on the board) or not at all.  A new link (the
session connects again) is not the one told goodbye: calls go out on it.
"""

from __future__ import annotations

import threading
from concurrent.futures import Future

from ...errors import FunctionFailed, MissingLinkError
from ...host.board import Board
from ...host.link import CallResult
from .failsafe import start_goodbye


class SaidGoodbye(MissingLinkError):
    """The board was told goodbye (the daemon stops): no more calls to it, nothing was sent."""


class Farewell:
    def __init__(self) -> None:
        self._lock = threading.RLock()  # (a call's callback may start another on this thread)
        self._told: Board | None = None
        self.answer: Future[CallResult] | None = None  #: the goodbye's answer, if one is out

    def said(self, board: Board | None) -> bool:
        """``board``'s link was told goodbye."""
        return board is not None and board is self._told

    def say(self, board: Board) -> Future[CallResult] | None:
        """Tell ``board`` goodbye, once (None: it has no ``a2jGoodbye``, or the link is gone);
        from now on no call of :meth:`call_future` reaches it."""
        with self._lock:
            if self._told is not board:
                self._told = board
                self.answer = start_goodbye(board)
            return self.answer

    def call_future(
        self, board: Board, name: str, payload: bytes = b"", timeout: float | None = None
    ) -> Future[CallResult]:
        """``board.call_future``, unless it was told goodbye (SaidGoodbye: nothing sent)."""
        with self._lock:
            if board is self._told:
                raise SaidGoodbye(f"{board.name}: {name} not sent: the board was told goodbye")
            return board.call_future(name, payload, timeout)

    def call(
        self, board: Board, name: str, payload: bytes = b"", timeout: float | None = None
    ) -> CallResult:
        """:meth:`call_future` and wait for it (as ``Board.call``)."""
        return board.link.wait(self.call_future(board, name, payload, timeout), timeout)

    def call_ok(
        self, board: Board, name: str, payload: bytes = b"", timeout: float | None = None
    ) -> bytes:
        """:meth:`call`, requiring return code 0 (as ``Board.call_ok``)."""
        result = self.call(board, name, payload, timeout)
        if result.code != 0:
            raise FunctionFailed(board.name, name, result.code, result.payload)
        return result.payload
