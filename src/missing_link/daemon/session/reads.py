"""What the session's supervisor asks of a served board and never waits for (liveness.py says
when): the keepalive that holds the board's failsafe off, an echo that times the round trip
when the board has no clock to probe, and, once a diagnostics period, the board's own counts
(its account of its grid, its failsafe's trips, its heap or stack, its log's counts).  Each is
one call in flight at most (inflight.py), answered on the board's reading thread."""

from __future__ import annotations

from collections.abc import Callable

from ...errors import MissingLinkError
from ...host.board import Board
from ...host.link import CallResult
from .alignment import parse_align_info
from .board_log import BoardLogPath
from .board_memory import FUNCTION as MEMORY_FUNCTION
from .board_memory import parse_memory
from .failsafe import Keepalive, parse_failsafe
from .inflight import BoardRead, InFlight
from .status import AlignInfo, FailsafeStatus, MemoryStatus


class BoardReads:
    def __init__(
        self,
        guarded: Callable[[Board], bool],
        on_rtt: Callable[[float], None],
        on_error: Callable[[MissingLinkError], None],
    ) -> None:
        """``guarded(board)``: the board has an actuator with a failsafe (its trips are read:
        a round trip a second costs); ``on_rtt(us)``: an echo's round trip; ``on_error``: a
        call of these failed."""
        self.alignment = BoardRead("a2jAlignInfo", parse_align_info, AlignInfo())
        self.failsafe = BoardRead("a2jFailsafe", parse_failsafe, FailsafeStatus(), guarded)
        self.memory = BoardRead(MEMORY_FUNCTION, parse_memory, MemoryStatus())
        self.keepalive = Keepalive()
        self._on_rtt = on_rtt
        self.echo = InFlight("a2jEcho", self._echoed, on_error)

    def counts(self, board: Board, limit: float, aligned: bool, log: BoardLogPath) -> None:
        """The board's own counts (``aligned``: its grid's too), each within ``limit`` s."""
        if aligned:
            self.alignment.refresh(board, limit)
        self.failsafe.refresh(board, limit)
        self.memory.refresh(board, limit)
        log.refresh(board, limit)  # (board_log.py)

    def _echoed(self, result: CallResult) -> None:
        if result.sent_ns and result.recv_ns > result.sent_ns:
            self._on_rtt((result.recv_ns - result.sent_ns) / 1000)
