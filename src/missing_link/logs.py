"""What reaches the log from outside: boards and network clients are untrusted, and so is the
rate at which they make us say things.

:class:`SafeLog` is a logging filter for the handler that writes to a terminal or a journal:
every record's message is made safe (``text.safe_text``: no control characters, so no escape
sequences and no forged extra lines; at most ``limit`` characters), and a message that repeats
(the same logger and format string) is written at most ``burst`` times per ``window_s``; the
rest are counted, and when the window ends one line says how many were held back.  The count
since start is ``SafeLog.suppressed`` (the daemon shows it on ``/diagnostics``).  Pure apart
from the clock it is handed.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

from .text import safe_text

LIMIT = 500  #: characters of one log line at most
BURST = 5  #: lines of one kind per window before it is held back
WINDOW_S = 60.0


class SafeLog(logging.Filter):
    suppressed = 0  #: lines held back since start, every handler together

    def __init__(
        self,
        limit: int = LIMIT,
        burst: int = BURST,
        window_s: float = WINDOW_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        super().__init__()
        self.limit, self.burst, self.window_s, self.clock = limit, burst, window_s, clock
        self._seen: dict[tuple[str, str], list[float]] = {}  # kind -> [window start, n, held]
        self._lock = threading.Lock()

    def filter(self, record: logging.LogRecord) -> bool:
        kind = (record.name, str(record.msg))
        now = self.clock()
        note = ""
        with self._lock:
            w = self._seen.get(kind)
            if w is None or now - w[0] >= self.window_s:
                if w is not None and w[2]:
                    held, window = int(w[2]), f"{self.window_s:g}"
                    note = f" ({held} more like this in the last {window} s held back)"
                w = self._seen[kind] = [now, 0, 0]
                if len(self._seen) > 1000:  # (kinds are format strings: few; a bound all the same)
                    self._seen = {kind: w}
            w[1] += 1
            if w[1] > self.burst:
                w[2] += 1
                SafeLog.suppressed += 1
                return False
        try:
            text = record.getMessage()
        except Exception:  # noqa: BLE001 - a record whose arguments do not fit its format
            text = str(record.msg)
        record.msg, record.args = safe_text(text, self.limit) + note, None
        return True
