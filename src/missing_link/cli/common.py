"""What every command shares: exit codes, argument types, opening a board, JSON output."""

from __future__ import annotations

import argparse
import json
import math
from typing import Any

from ..host.board import Board

EXIT_FAIL = 1
EXIT_USAGE = 2
EXIT_INTERRUPTED = 130


def parse_hex(text: str) -> bytes:
    cleaned = text.replace(" ", "").replace(":", "")
    try:
        return bytes.fromhex(cleaned)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--hex {text!r} is not hex bytes (e.g. 01ff or '01 ff')"
        ) from None


def _number(text: str, allow_zero: bool) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value) or value < 0 or (value == 0 and not allow_zero):
        raise argparse.ArgumentTypeError(f"{text} must be a number {'>=' if allow_zero else '>'} 0")
    return value


def positive(text: str) -> float:
    return _number(text, allow_zero=False)


def non_negative(text: str) -> float:
    return _number(text, allow_zero=True)


def count_arg(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"{value} must be 0 or more")
    return value


def port_arg(text: str) -> int:
    value = count_arg(text)
    if value > 65535:
        raise argparse.ArgumentTypeError(f"{value} is not a TCP port (0..65535)")
    return value


def open_url(args: argparse.Namespace) -> Board:
    return Board.open(args.url, timeout=args.timeout)


def emit_json(obj: Any) -> None:
    print(json.dumps(obj, sort_keys=False), flush=True)


def with_url(sp: argparse.ArgumentParser) -> None:
    """The board URL and the per-call timeout: every command that talks to one board."""
    sp.add_argument("url", help="board URL, e.g. serial:///dev/ttyACM0 or tcp://127.0.0.1:5000")
    sp.add_argument(
        "--timeout", type=positive, default=1.0, help="per-call timeout in seconds (1.0)"
    )
