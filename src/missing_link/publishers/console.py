"""``console``: one line per update on stdout, rate-limited per topic (option ``rate_hz``)."""

from __future__ import annotations

import sys
import threading
import time
from typing import Any, TextIO

from ..descriptors import Transducer
from ..errors import without_prefix
from ..topics import Update
from .base import Publisher


def format_values(t: Transducer, values: list[Any]) -> str:
    """Values as a user reads them: in the descriptor's unit where it gives a scale (the servo's
    raw 20 is 14.17 deg), the raw numbers after them; ``-`` for N/A."""
    raw = "[" + " ".join("-" if v is None else str(v) for v in values) + "]"
    unit = f" {t.unit}" if t.unit else ""
    if not t.scaled:
        return raw + unit
    real = " ".join("-" if v is None else f"{t.in_unit(v):.4g}" for v in values)
    return f"[{real}]{unit} (raw {raw})"


class ConsolePublisher(Publisher):
    name = "console"

    def __init__(self, options: dict[str, Any] | None = None, out: TextIO | None = None) -> None:
        opts = options or {}
        rate = float(opts.get("rate_hz", 2.0))
        self.period = 1.0 / rate if rate > 0 else 0.0
        self.out = out or sys.stdout
        self._next: dict[str, float] = {}
        self._said: dict[str, str] = {}  #: who is in error -> what was said of it
        self._lock = threading.Lock()

    def publish(self, update: Update) -> None:
        now = time.monotonic()
        name = update.topic.name
        if now < self._next.get(name, 0.0):
            return
        self._next[name] = now + self.period
        text = format_values(update.topic.transducer, update.values)
        with self._lock:
            print(f"{update.stamp_ns / 1e9:.6f} {name} {text}", file=self.out, flush=True)

    def diagnostics(self, status: list[dict[str, Any]], now_ns: int) -> None:
        """A board or publisher in error, said when that changes (not every round: a board
        that is not there is retried with backoff, quietly); and when it is well again."""
        for s in status:
            who = s.get("board") or f"publisher {s.get('publisher')}"
            if s.get("level", 0) >= 2:
                said = without_prefix(str(s.get("url", "")), str(s.get("message", "")))
                line = f"{who}: {s.get('state', 'failed')}: {said}"
                if self._said.get(who) == said:
                    continue
                self._said[who] = said
            elif self._said.pop(who, None) is not None:
                line = f"{who}: {s.get('state', 'ok')}"
            else:
                continue
            with self._lock:
                print(f"{now_ns / 1e9:.6f} /diagnostics {line}", file=self.out, flush=True)
