"""What every command shares: exit codes, argument types, opening a board, JSON output.

Light on purpose: the parser (commands.py) uses the argument types for every command, so this
imports nothing of the board, the daemon or json until a command asks."""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from ..host.board import Board

EXIT_FAIL = 1
EXIT_USAGE = 2
EXIT_INTERRUPTED = 130


def error(text: object, code: int = EXIT_FAIL) -> int:
    """Say ``text`` as the command's one-line error on stderr; the exit code to return."""
    print(f"missing-link: error: {text}", file=sys.stderr)
    return code


#: the longest one call may wait for its reply (s).  A board answers in milliseconds; a
#: timeout reaches the link and, through a daemon, its control endpoint, where a huge one
#: (1e308, inf) would hold a dead board "up": it is refused here, before anything is sent.
MAX_TIMEOUT_S = 60.0
#: the longest a command runs or waits (--duration, --wait-up, ...): a year
MAX_DURATION_S = 365 * 86400.0
#: the fastest a virtual board's ``--rate`` may be (the rate sim's own limit)
MAX_RATE_HZ = 100_000.0


def add_timeout(sp: argparse.ArgumentParser) -> None:
    """``--timeout``: every command that calls a board."""
    sp.add_argument(
        "--timeout",
        type=timeout_arg,
        default=1.0,
        help="per-call timeout in seconds (1.0; at most 60)",
    )


def parse_hex(text: str) -> bytes:
    cleaned = text.replace(" ", "").replace(":", "")
    try:
        return bytes.fromhex(cleaned)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--hex {text!r} is not hex bytes (e.g. 01ff or '01 ff')"
        ) from None


def number(
    low: float = -math.inf, high: float = math.inf, *, above: bool = False, unit: str = ""
) -> Callable[[str], float]:
    """An argument type: a finite number from ``low`` (excluded if ``above``) to ``high``.
    NaN, infinities and numbers out of range are refused with one line naming the limit."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"{text} is not a finite number")
        if value < low or (above and value == low):
            raise argparse.ArgumentTypeError(
                f"{text} must be a number {'>' if above else '>='} {low:g}"
            )
        if value > high:
            most = f"{high:.0f}" if float(high).is_integer() else f"{high:g}"
            raise argparse.ArgumentTypeError(f"{text} is over {most}{unit}, the most allowed")
        return value

    parse.__name__ = "number"  # (argparse names the type in some messages)
    return parse


#: a call's timeout: > 0, at most MAX_TIMEOUT_S
timeout_arg = number(0, MAX_TIMEOUT_S, above=True, unit=" s")
#: how long to run or wait: 0 (for ever, where the command says so) up to MAX_DURATION_S
seconds_arg = number(0, MAX_DURATION_S, unit=" s")
#: a period or a time that must pass: > 0, up to MAX_DURATION_S
positive = number(0, MAX_DURATION_S, above=True, unit=" s")
#: any finite number (a clock's offset or skew)
finite = number()


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
    from ..host.board import Board

    return Board.open(args.url, timeout=args.timeout)


def emit_json(obj: Any) -> None:
    import json

    print(json.dumps(obj, sort_keys=False), flush=True)
