"""What reaches the log from outside: boards and network clients are untrusted, and so is the
rate at which they make us, or the libraries we run, say things.

:class:`SafeLog` is a logging filter for the handler that writes to a terminal or a journal, and
:func:`install` puts one such handler on the *root* logger, so every logger the process runs
goes through it: ours, and asyncio's, websockets', zenoh's, rclpy's.  For every record:

* its message is made safe (``text.safe_text``: no control characters, so no escape sequences
  and no forged extra lines; at most ``limit`` characters);
* a message that repeats - the same logger and message template: the format string, or for a
  message formatted before it was logged (asyncio's), its first line with the numbers taken out
  - is written at most ``burst`` times per ``window_s``; and one logger at most ``per_logger``
  times per window, whatever it says.  The rest are counted, and when the window ends one line
  says how many were held back;
* a traceback from a library's logger is folded into one line (``(ValueError: ...)``): a
  client's bad frame is not twenty lines; ours (``missing_link.*``: a bug) keep theirs, cleaned
  line by line and cut at ``TRACE_LINES``.

:func:`counts` returns what was held back and folded since start (the daemon shows it on
``/diagnostics``).  Pure apart from the clock it is handed; ``install`` is the shell.

:class:`ErrorCounts` is the other half: where an exception is caught so that a thread goes on
(a supervisor, the I/O loop, a publisher's thread, the fan-out), it is counted *by kind* (its
class and where it was caught), the first of each kind is logged with its traceback and the
rest are only counted, and ``to_json()`` puts the counts in the status and ``/diagnostics``.
Nothing is spent on it while nothing fails.
"""

from __future__ import annotations

import logging
import re
import sys
import threading
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from typing import IO, Any

from .text import safe_text

LIMIT = 500  #: characters of one log line at most
BURST = 5  #: lines of one kind per window before it is held back
PER_LOGGER = 30  #: lines of one logger per window, of any kind
WINDOW_S = 60.0
TRACE_LINES = 60  #: lines of one of our own tracebacks at most
_NUMBERS = re.compile(r"0x[0-9a-fA-F]+|\d+")


def template(record: logging.LogRecord) -> str:
    """What makes two records "the same message": the format string, or the first line of a
    message formatted before it was logged with its numbers taken out."""
    msg = str(record.msg)
    if record.args:
        return msg
    return _NUMBERS.sub("#", msg.split("\n", 1)[0][:200])


class SafeLog(logging.Filter):
    suppressed = 0  #: lines held back since start, every handler together
    folded = 0  #: library tracebacks folded into their line since start
    held: dict[str, int] = {}  #: lines held back since start, per logger

    def __init__(
        self,
        limit: int = LIMIT,
        burst: int = BURST,
        window_s: float = WINDOW_S,
        clock: Callable[[], float] = time.monotonic,
        per_logger: int = PER_LOGGER,
    ) -> None:
        super().__init__()
        self.limit, self.burst, self.window_s, self.clock = limit, burst, window_s, clock
        self.per_logger = per_logger
        self._seen: dict[tuple[str, str], list[float]] = {}  # kind -> [window start, n, held]
        self._loggers: dict[str, list[float]] = {}  # logger -> [window start, n]
        self._lock = threading.Lock()

    def filter(self, record: logging.LogRecord) -> bool:
        kind = (record.name, template(record))
        now = self.clock()
        note = ""
        with self._lock:
            w = self._seen.get(kind)
            if w is None or now - w[0] >= self.window_s:
                if w is not None and w[2]:
                    held, window = int(w[2]), f"{self.window_s:g}"
                    note = f" ({held} more like this in the last {window} s held back)"
                w = self._seen[kind] = [now, 0, 0]
                if len(self._seen) > 1000:  # (kinds are templates: few; a bound all the same)
                    self._seen = {kind: w}
            lw = self._loggers.get(record.name)
            if lw is None or now - lw[0] >= self.window_s:
                lw = self._loggers[record.name] = [now, 0]
                if len(self._loggers) > 1000:
                    self._loggers = {record.name: lw}
            w[1] += 1
            lw[1] += 1
            if w[1] > self.burst or lw[1] > self.per_logger:
                w[2] += 1
                SafeLog.suppressed += 1
                SafeLog.held[record.name] = SafeLog.held.get(record.name, 0) + 1
                return False
        try:
            text = record.getMessage()
        except Exception:  # noqa: BLE001 - arguments that do not fit the format: said as is
            text = f"{record.msg} (its arguments did not fit: {record.args!r})"
        text = " | ".join(x for x in text.splitlines() if x.strip())  # (one line, still readable)
        record.msg, record.args = safe_text(text, self.limit) + note, None
        self._traceback(record)
        return True

    def _traceback(self, record: logging.LogRecord) -> None:
        record.stack_info = None
        info = record.exc_info
        if not info or info[1] is None:
            record.exc_info, record.exc_text = None, None
            return
        if record.name == "missing_link" or record.name.startswith("missing_link."):
            lines = "".join(traceback.format_exception(*info)).rstrip("\n").split("\n")
            cut = [safe_text(x, self.limit) for x in lines[:TRACE_LINES]]
            if len(lines) > TRACE_LINES:
                cut.append(f"... ({len(lines) - TRACE_LINES} more lines)")
            record.exc_text = "\n".join(cut)
            return
        exc = info[1]
        record.msg = f"{record.msg} ({safe_text(f'{type(exc).__name__}: {exc}', 200)})"
        record.exc_info, record.exc_text = None, None
        with self._lock:
            SafeLog.folded += 1


def counts() -> dict[str, Any]:
    """What the log held back and folded since start, for the daemon's diagnostics:
    ``lines_held_back``, ``tracebacks_folded``, and ``held_back_from`` (the loggers that had
    lines held back, most first)."""
    top = sorted(SafeLog.held.items(), key=lambda kv: -kv[1])[:5]
    return {
        "lines_held_back": SafeLog.suppressed,
        "tracebacks_folded": SafeLog.folded,
        "held_back_from": ", ".join(f"{name} {n}" for name, n in top),
    }


@dataclass
class ErrorKind:
    """One kind of caught exception: how often, and the first one."""

    kind: str  #: ``ValueError in publish``: its class and where it was caught
    count: int
    first: str  #: the first one's message and where it was raised (``codec.py:88 encode``)
    traceback: str  #: the first one's traceback


MAX_KINDS = 32  #: kinds kept apart per counter; more are counted under ``OTHER``
OTHER = "other kinds"


class ErrorCounts:
    """Exceptions caught where a thread must go on, counted by kind; the first of each kind is
    logged (``log``, with its traceback: ``name`` says whose), the rest only counted.  Safe to
    call from any thread; costs nothing until something fails."""

    def __init__(self, log: logging.Logger, name: str = "") -> None:
        self.log, self.name = log, name
        self.total = 0  #: every exception counted
        self._kinds: dict[str, ErrorKind] = {}
        self._lock = threading.Lock()

    def caught(self, where: str, exc: BaseException, what: str = "") -> None:
        """Count ``exc``, caught at ``where`` (``publish``, ``reactor round``); ``what``: a
        line for the log that says what failed (default: ``where``)."""
        kind = f"{type(exc).__name__} in {where}"
        with self._lock:
            self.total += 1
            known = self._kinds.get(kind)
            if known is None and len(self._kinds) >= MAX_KINDS:
                kind = OTHER
                known = self._kinds.get(kind)
            if known is not None:
                known.count += 1
                return
            tb = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
            self._kinds[kind] = ErrorKind(kind, 1, _first(exc), tb)
        who = f"{self.name}: " if self.name else ""
        # (formatted here: the log filter tells kinds apart by their text, so one kind's first
        # line is never held back for another's)
        self.log.error(f"{who}{what or where} failed ({kind}: counted, said once)", exc_info=exc)

    def kinds(self) -> list[ErrorKind]:
        """The kinds so far, most frequent first (copies)."""
        with self._lock:
            out = [ErrorKind(k.kind, k.count, k.first, k.traceback) for k in self._kinds.values()]
        return sorted(out, key=lambda k: -k.count)

    def summary(self, limit: int = 5) -> str:
        """One line: ``ValueError in publish x3 (bad value at codec.py:88 encode); ...``."""
        kinds = self.kinds()
        text = "; ".join(f"{k.kind} x{k.count} ({k.first})" for k in kinds[:limit])
        if len(kinds) > limit:
            text += f"; {len(kinds) - limit} more kinds"
        return text

    def to_json(self) -> dict[str, Any]:
        """For a status: ``errors`` (how many were caught) and ``error_kinds`` (``summary``)."""
        if not self.total:
            return {"errors": 0, "error_kinds": ""}
        return {"errors": self.total, "error_kinds": self.summary()}


def _first(exc: BaseException) -> str:
    """An exception's message and the place it was raised, in one short line."""
    tb = exc.__traceback__
    while tb is not None and tb.tb_next is not None:
        tb = tb.tb_next
    at = ""
    if tb is not None:
        code = tb.tb_frame.f_code
        at = f" at {code.co_filename.rsplit('/', 1)[-1]}:{tb.tb_lineno} {code.co_name}"
    return safe_text(f"{exc}{at}" if str(exc) else at.strip(), 160)


_installed: logging.Handler | None = None


def install(stream: IO[str] | None = None, level: int = logging.WARNING) -> logging.Handler:
    """One handler on the root logger that writes ``level`` and up as plain lines to
    ``stream`` (stderr) through a :class:`SafeLog`; an uncaught exception in a thread is logged
    through it too (``missing_link.thread``) instead of printed whole.  Again: replaces it."""
    global _installed
    root = logging.getLogger()
    if _installed is not None:
        root.removeHandler(_installed)
    handler = logging.StreamHandler(stream if stream is not None else sys.stderr)
    handler.setFormatter(logging.Formatter("%(message)s"))
    handler.setLevel(level)
    handler.addFilter(SafeLog())
    root.addHandler(handler)
    _installed = handler
    threading.excepthook = _thread_died
    return handler


def _thread_died(args: threading.ExceptHookArgs) -> None:
    if args.exc_type is SystemExit:
        return
    name = args.thread.name if args.thread is not None else "?"
    info = (args.exc_type, args.exc_value, args.exc_traceback)
    logging.getLogger("missing_link.thread").error("thread %s died", name, exc_info=info)  # type: ignore[arg-type]
