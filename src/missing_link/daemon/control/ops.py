"""What the control endpoint (endpoint.py) serves for a daemon: a board name or URL in, JSON out.

The daemon hands these handlers three of its verbs (find a session, a session that is up with
its board, a gated call), never itself; endpoint.py serves them on its socket.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from ...errors import ConfigError
from ...host.board import Board
from ...host.board_log import LogLine
from ...host.clock import SYSTEM_CLOCK, Clock
from ...host.config import describe_keys
from ...host.link import CallResult
from ..session.session import BoardSession
from .updates import BoardUpdates

Handler = Callable[[dict[str, Any]], dict[str, Any]]


def control_handlers(
    session: Callable[[str], BoardSession],
    up: Callable[[str], tuple[BoardSession, Board]],
    call: Callable[..., CallResult],
    configure: Callable[..., dict[str, Any]],
    reset: Callable[..., dict[str, Any]],
    log_line: Callable[[LogLine], None] | None = None,
    clock: Clock = SYSTEM_CLOCK,
    gate_board: Callable[[BoardSession, str], None] = lambda s, what: None,
) -> dict[str, Handler]:
    """``session(board)``: its session; ``up(board)``: the session and its board, or
    BoardError when it is not up; ``call(board, function, payload, timeout, by=)``: a call
    through the daemon's allow-list; ``configure(board, values, save, by=)`` and ``reset(board,
    erase, by=)``: a configuration change through it (an actuator's keys are commands);
    ``log_line``: a line of a board's log to every face (the firmware updates' ops, updates.py:
    ``update``, ``update_status``, ``release``, ``retake``); ``gate_board(session, what)``: the
    allow-list on an op that changes what every actuator of a board does or lets go of its port
    (``update``, ``release``: CommandRefused unless it admits them all)."""

    def find(r: dict[str, Any]) -> dict[str, Any]:
        s = session(text(r, "board"))
        return {"name": s.name, "url": s.spec.url, "state": s.state}

    def info(r: dict[str, Any]) -> dict[str, Any]:
        b = up(text(r, "board"))[1]
        return {**b.describe(), "transds_text": b.transds_text, "via": "daemon"}

    def do_call(r: dict[str, Any]) -> dict[str, Any]:
        try:
            payload = bytes.fromhex(text(r, "payload", ""))
        except ValueError:
            raise ConfigError('call: payload: expected hex digits, e.g. "01ff"') from None
        board, function = text(r, "board"), text(r, "function")
        got = call(board, function, payload, r.get("timeout"), by="control")
        return {"code": got.code, "payload": got.payload.hex()}

    def config(r: dict[str, Any]) -> dict[str, Any]:
        name = text(r, "board")
        s, b = up(name)
        wanted = r.get("set") or {}
        if not isinstance(wanted, dict):
            raise ConfigError("config: set must be an object of key: value")
        if r.get("reset"):
            reset(name, bool(r.get("erase")), by="control")
        if wanted or r.get("save"):
            configure(name, wanted, bool(r.get("save")), by="control")
        values = s.run_config.read()
        keys = describe_keys(b.settings.keys(), values)
        return {"values": values, "keys": keys, "state": b.settings.state}

    ops = {"find": find, "info": info, "call": do_call, "config": config}
    updates = BoardUpdates(session, log_line or (lambda line: None), clock, gate_board)
    return {**ops, **updates.handlers()}


def text(request: dict[str, Any], key: str, default: str | None = None) -> str:
    """A request's text field: ConfigError (a usage error) when it is missing or not text."""
    value = request.get(key, default)
    if not isinstance(value, str):
        what = "missing" if value is None else "expected text"
        raise ConfigError(f"{request.get('op')}: {key}: {what}")
    return value
