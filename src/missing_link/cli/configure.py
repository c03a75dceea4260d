"""``config``: a board's run-time configuration (docs/configuration.md): print it, set keys
(all or none), keep them on the board, or go back to the board file's defaults.  Through the
daemon that holds the board when one does (remote.py)."""

from __future__ import annotations

import argparse
from typing import Any

from ..errors import ConfigError
from ..host.board import Board
from ..host.config import ST_DIRTY, ST_LOADED, ST_SAVED, describe_keys
from .common import emit_json
from .remote import RemoteBoard, reach


def parse_assignments(items: list[str]) -> dict[str, str]:
    out: dict[str, str] = {}
    for item in items:
        key, sep, value = item.partition("=")
        key, value = key.strip(), value.strip()
        if not sep or not key or not value:
            raise ConfigError(f"{item!r}: expected KEY=VALUE, e.g. dist_ir.rate_hz=10")
        if key in out:
            raise ConfigError(f"{key} given twice")
        out[key] = value
    return out


def state_text(state: int) -> str:
    names = ((ST_SAVED, "saved"), (ST_LOADED, "loaded at boot"), (ST_DIRTY, "changed"))
    return ", ".join(n for bit, n in names if state & bit) or "defaults, nothing saved"


def _apply(
    board: Board | RemoteBoard, args: argparse.Namespace, wanted: dict[str, str]
) -> dict[str, Any]:
    """The change asked for, then {"values", "keys", "state"}."""
    if isinstance(board, RemoteBoard):
        return board.config_request(wanted, save=args.save, reset=args.reset, erase=args.erase)
    settings = board.settings
    keys = settings.keys()
    if wanted:
        settings.check(wanted)  # every key and value first: nothing is sent if one is wrong
    if args.reset:
        board.reset_config(args.erase)
    if wanted or args.save:
        board.configure(wanted, save=args.save)
    values = board.config()
    return {"values": values, "keys": describe_keys(keys, values), "state": settings.state}


def cmd_config(args: argparse.Namespace) -> int:
    wanted = parse_assignments(args.assign)
    if args.erase and not args.reset:
        raise ConfigError("--erase goes with --reset")
    with reach(args.url, args.timeout) as board:
        got = _apply(board, args, wanted)
        name = board.name
    if args.json:
        out: dict[str, Any] = {"board": name, "values": got["values"]}
        out["state"] = state_text(int(got["state"]))
        if args.verbose:
            out["keys"] = got["keys"]
        emit_json(out)
        return 0
    width = max((len(k["key"]) for k in got["keys"]), default=0)
    if args.verbose:
        print(f"# {name}: {state_text(int(got['state']))}")
    for k in got["keys"]:
        line = f"{k['key']:<{width}} = {_text(k['value'])}"
        if args.verbose:
            extra = f"default {_text(k['default'])}; {k['allowed']}"
            line += f"    # {extra}{'; read-only' if k['read_only'] else ''}"
        print(line)
    return 0


def _text(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return f"{v:g}"
    return str(v)
