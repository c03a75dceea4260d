"""The host's side of a board's failsafe (board/failsafe.py; docs/hardware.md, "Failsafe").

A board makes an actuator safe when no frame has come from the host for its ``failsafe_ms`` (a
run-time key).  So that only a host that is gone trips it, the session keeps a quiet link
talking: a frame (``a2jEcho``) every third of the shortest ``failsafe_ms`` on the board,
whatever else is going on, with at most one of them out at a time (``Keepalive``: a request
queued behind a frozen board is no frame to it, and a backlog of them would only delay
everything else).  When the daemon stops it says goodbye first (``a2jGoodbye``: every actuator
safe at once), waiting a bounded time for the answer; and a board's own count of trips
(``a2jFailsafe``) is read once per diagnostics period into the status (``failsafe_trips``), on
boards with a ``failsafe_ms`` key (an actuator that can be made safe) only, in the background
like the keepalive (never waited for: the session's supervisor must not be held up).
"""

from __future__ import annotations

import struct
from collections.abc import Mapping
from concurrent.futures import Future

from ...errors import MissingLinkError
from ...host.board import Board
from ...host.config import Value
from ...host.link import CallResult
from .inflight import InFlight
from .status import FailsafeStatus

#: the keepalive never runs faster than this (s), however short a failsafe_ms
MIN_KEEPALIVE_S = 0.02
#: a keepalive's own timeout never shorter than this (s): a loaded host answers late
MIN_KEEPALIVE_TIMEOUT_S = 0.1
GOODBYE_TIMEOUT_S = 0.3


def failsafe_ms(board: Board, values: Mapping[str, Value]) -> list[int]:
    """Every actuator's ``failsafe_ms`` on this board (0: disarmed; none: no failsafe)."""
    if "a2jFailsafe" not in board.index:
        return []
    return [v for k, v in values.items() if k.endswith(".failsafe_ms") and isinstance(v, int)]


def keepalive_s(board: Board, values: Mapping[str, Value]) -> float | None:
    """How often the host must send a frame to this board (None: it has no failsafe armed)."""
    ms = [v for v in failsafe_ms(board, values) if v]
    if not ms:
        return None
    return max(MIN_KEEPALIVE_S, min(ms) / 3000)


class Keepalive:
    """One ``a2jEcho`` to the board, not waited for; at most one out at a time."""

    def __init__(self) -> None:
        self.call = InFlight("a2jEcho", lambda result: None)

    def send(self, board: Board, keep: float, limit: float) -> bool:
        """Send one unless the last is still out (True: sent).  Its timeout is the period
        (a lost one frees the slot for the next in time), within ``limit``."""
        return self.call.start(board, b"", min(limit, max(keep, MIN_KEEPALIVE_TIMEOUT_S)))


def start_goodbye(board: Board) -> Future[CallResult] | None:
    """Send ``a2jGoodbye`` (its actuators go to their safe states now); None when the board has
    none or the link is gone.  Wait for it with :func:`wait_goodbye`."""
    if "a2jGoodbye" not in board.index or not board.alive:
        return None
    try:
        return board.call_future("a2jGoodbye", b"", timeout=GOODBYE_TIMEOUT_S)
    except MissingLinkError:
        return None  # (a link closing under the call)


def wait_goodbye(fut: Future[CallResult] | None, limit: float = GOODBYE_TIMEOUT_S + 0.2) -> None:
    """Wait for a goodbye's answer, at most ``limit`` s: stopping must never hang on a board
    (nor raise), and the board trips on its own after failsafe_ms anyway."""
    if fut is None:
        return
    try:
        fut.result(max(0.0, limit))
    except (MissingLinkError, TimeoutError):  # (unanswered: the board trips on its own)
        pass


def goodbye(board: Board) -> None:
    """Tell the board the host is going, waiting a bounded time for its answer."""
    wait_goodbye(start_goodbye(board))


def parse_failsafe(p: bytes) -> FailsafeStatus:
    """``a2jFailsafe``'s reply: the board's trips and the age of the last one."""
    if len(p) != 8:
        return FailsafeStatus(problem=f"a reply of {len(p)} bytes, not 8")
    trips, age = struct.unpack("<II", p)
    return FailsafeStatus(trips, None if age == 0xFFFFFFFF else age)
