"""The host's side of a board's failsafe (board/failsafe.py; docs/hardware.md, "Failsafe").

A board makes an actuator safe when no frame has come from the host for its ``failsafe_ms`` (a
run-time key).  So that only a host that is gone trips it, the session keeps a quiet link
talking: a frame (``a2jEcho``, not waited for) every third of the shortest ``failsafe_ms`` on
the board, whatever else is going on.  When the daemon stops it says goodbye first
(``a2jGoodbye``: every actuator safe at once), and a board's own count of trips
(``a2jFailsafe``) is read once per diagnostics period into the status (``failsafe_trips``), on
boards with a ``failsafe_ms`` key (an actuator that can be made safe) only.
"""

from __future__ import annotations

import struct
from collections.abc import Mapping
from typing import Any

from ..errors import MissingLinkError
from ..host.board import Board
from ..host.config import Value

#: the keepalive never runs faster than this (s), however short a failsafe_ms
MIN_KEEPALIVE_S = 0.02
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


def keep_alive(board: Board) -> None:
    """One frame to the board, not waited for (its reply or its loss count elsewhere)."""
    try:
        board.call_future("a2jEcho", b"")
    except MissingLinkError:
        pass  # (a link going down: the session notices)


def goodbye(board: Board) -> None:
    """Tell the board the host is going: its actuators go to their safe states now."""
    if "a2jGoodbye" not in board.index or not board.alive:
        return
    # Waited for here with its own limit: stopping must never hang on a board (nor raise: a
    # link closing under the call may leave it unanswered), and the board trips on its own
    # after failsafe_ms anyway.
    try:
        board.call_future("a2jGoodbye", b"", timeout=GOODBYE_TIMEOUT_S).result(
            GOODBYE_TIMEOUT_S + 0.2
        )
    except (MissingLinkError, TimeoutError):
        pass


class FailsafeInfo:
    def __init__(self) -> None:
        self.info: dict[str, Any] = {}

    def refresh(self, board: Board, values: Mapping[str, Value]) -> None:
        # only a board with an actuator that has a failsafe (a round trip a second costs)
        if not failsafe_ms(board, values):
            return
        try:
            p = board.call_ok("a2jFailsafe")
        except MissingLinkError:
            return
        if len(p) != 8:
            self.info = {"failsafe": f"a reply of {len(p)} bytes, not 8"}
            return
        trips, age = struct.unpack("<II", p)
        self.info = {
            "failsafe_trips": trips,
            "failsafe_last_trip_ms": None if age == 0xFFFFFFFF else age,
        }
