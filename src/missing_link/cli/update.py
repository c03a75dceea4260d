"""``update``: a board's firmware updated where it is mounted, over its link (deploy/update.py;
docs/hardware.md, "Updates over the link"): through the daemon that holds the board when one
does, else on the board's URL.  A progress bar on stderr, the summary on stdout (old and new
version and hash, bytes, time); exit 0 only when the new firmware runs, confirmed."""

from __future__ import annotations

import argparse
import sys
import time
from typing import TextIO

from ..errors import BadURL
from .common import EXIT_FAIL, emit_json

BAR = 30  #: the bar's width in characters
EVERY_S = 0.1  #: a terminal's bar is drawn at most this often


class ProgressBar:
    """``report(state, done, total)`` drawn on ``out``: a bar redrawn in place on a terminal,
    else a line at each new state and every quarter of the bytes."""

    def __init__(self, out: TextIO) -> None:
        self.out = out
        self.tty = out.isatty()
        self._state = ""
        self._quarter = -1
        self._drawn = 0.0
        self._open = False  # a bar is on the line

    def report(self, state: str, done: int, total: int) -> None:
        if self.tty:
            now = time.monotonic()
            if state == self._state and now - self._drawn < EVERY_S and done < total:
                return
            self._drawn = now
            self.out.write("\r\x1b[K" + self._line(state, done, total))
            self._open = True
        else:
            quarter = 4 * done // total if total else -1
            if state == self._state and quarter == self._quarter:
                return
            self._quarter = quarter
            self.out.write(self._line(state, done, total) + "\n")
        self._state = state
        self.out.flush()

    def say(self, text: str) -> None:
        self.end()
        self.out.write(text + "\n")
        self.out.flush()

    def end(self) -> None:
        if self._open:
            self.out.write("\n")
            self.out.flush()
            self._open = False

    @staticmethod
    def _line(state: str, done: int, total: int) -> str:
        if not total:
            return f"update: {state}"
        filled = BAR * done // total
        bar = "#" * filled + "." * (BAR - filled)
        return f"update: {state:<11} [{bar}] {100 * done // total:3d}%  {done / 1024:.1f}/" \
            f"{total / 1024:.1f} KiB"  # fmt: skip


def cmd_update(args: argparse.Namespace) -> int:
    from ..deploy.boardfile import load_board_file
    from ..deploy.update import (
        daemon_holding,
        micropython_image,
        target_of,
        update_avr,
        update_direct,
        update_via_daemon,
    )

    bf = load_board_file(args.boardfile)
    target = target_of(bf, args.id)
    daemon = daemon_holding(args.target)
    if daemon is None and "://" not in args.target:
        raise BadURL(
            f"{args.target!r} is not a board URL (serial:///dev/ttyACM0, tcp://HOST:PORT, ...), "
            "and no running daemon holds a board of that name"
        )
    bar = ProgressBar(sys.stderr)
    try:
        if bf.is_avr:
            outcome = update_avr(bf, args.target, target, bar.report, bar.say, daemon=daemon,
                                 timeout=args.timeout)  # fmt: skip
        elif daemon is not None:
            image = micropython_image(bf)
            outcome = update_via_daemon(daemon, args.target, image, target, args.trial, bar.report)
        else:
            image = micropython_image(bf)
            outcome = update_direct(args.target, image, target, args.trial, bar.report,
                                    args.timeout)  # fmt: skip
    finally:
        bar.end()
    if args.json:
        emit_json(outcome.to_json())
    else:
        print(outcome.summary(), flush=True)
    return 0 if outcome.ok else EXIT_FAIL
