"""A call the session's supervisor makes and never waits for: at most one of a kind in flight.

The link sends one request at a time, in order (window 1: j2a/connection.py), and a request's
timeout starts only when it is sent.  So a supervisor that waited for its calls would wait
behind everything queued ahead of them (a frozen board: every queued request's whole timeout in
turn), and one that queued a call on every tick would build a backlog.  Each kind of call the
supervisor makes (the keepalive, the heartbeat echo, the board's failsafe and alignment counts)
is an ``InFlight``: ``start`` sends it unless one is still out, and the reply (or the error) is
handed to a callback on the thread that reads the board.  A closed link fails every pending
call, so a slot is never held past its link.  An exception from a callback (a bug: a board's
reply is checked there) is counted by kind in the link's ``faults``, which the session shows.

:class:`BoardRead` is the one way the session reads a board's own count in the background (its
alignment, failsafe and memory figures): an ``InFlight`` whose reply is parsed into ``status``.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from concurrent.futures import Future
from typing import Generic, TypeVar

from ...errors import MissingLinkError
from ...host.board import Board
from ...host.link import CallResult

S = TypeVar("S")


class InFlight:
    def __init__(
        self,
        function: str,
        on_reply: Callable[[CallResult], None],
        on_error: Callable[[MissingLinkError], None] = lambda e: None,
    ) -> None:
        """``on_reply(result)`` / ``on_error(error)``: on the board's reading thread (or at
        once on the caller's, for a link already gone); keep them short."""
        self.function = function
        self._on_reply = on_reply
        self._on_error = on_error
        self._lock = threading.Lock()
        self._busy = False
        self._token = 0  # which start() the pending reply belongs to
        self.sent = 0  #: calls started
        self.skipped = 0  #: starts refused: the previous call was still in flight

    @property
    def busy(self) -> bool:
        return self._busy

    def start(self, board: Board, payload: bytes = b"", timeout: float | None = None) -> bool:
        """Send the call unless one is in flight; True when it was sent."""
        with self._lock:
            if self._busy:
                self.skipped += 1
                return False
            self._busy = True  # (before the call: its reply may come before call_future returns)
            self._token += 1
            token = self._token
        try:
            fut = board.call_future(self.function, payload, timeout)
        except MissingLinkError as e:  # the link is gone: the session notices
            self._release(token)
            self._on_error(e)
            return False
        self.sent += 1
        fut.add_done_callback(lambda f: self._done(token, f, board))
        return True

    def _release(self, token: int) -> None:
        with self._lock:
            if token == self._token:
                self._busy = False

    def _done(self, token: int, fut: Future[CallResult], board: Board) -> None:
        # (on the reading thread: nothing may escape, or concurrent.futures logs it and the
        # count is lost)
        self._release(token)
        try:
            result = fut.result()
        except MissingLinkError as e:
            try:
                self._on_error(e)
            except Exception as bug:  # noqa: BLE001 - a callback's bug: counted, said once
                board.link.faults.caught(f"{self.function} error callback", bug)
            return
        except Exception as e:  # noqa: BLE001 - a future failed with a bug: counted, said once
            board.link.faults.caught(self.function, e)
            return
        try:
            self._on_reply(result)
        except Exception as e:  # noqa: BLE001 - (as above: a board's reply may be anything)
            what = f"handling the {self.function} reply"
            board.link.faults.caught(f"{self.function} reply", e, what)


class BoardRead(Generic[S]):
    """A board's count, read in the background: ``refresh`` (once a diagnostics period, the
    supervisor's thread) asks unless a read is out, and the reply, parsed (``parse``: the
    payload -> a status that says what was wrong with it, never raises for a board's bytes),
    becomes ``status``; a refused read keeps what was there.  ``wanted(board)``: whether to
    ask this board (by default: it has the function)."""

    def __init__(
        self,
        function: str,
        parse: Callable[[bytes], S],
        status: S,
        wanted: Callable[[Board], bool] | None = None,
    ) -> None:
        self.status = status
        self._parse = parse
        self._wanted = wanted or (lambda board: function in board.index)
        self._read = InFlight(function, self._took)

    def refresh(self, board: Board, timeout: float) -> None:
        if self._wanted(board):
            self._read.start(board, b"", timeout)

    def _took(self, result: CallResult) -> None:
        if result.code == 0:  # (a failed read: the status keeps what it had)
            self.status = self._parse(result.payload)
