"""``console``: one line per update on stdout, rate-limited per topic (option ``rate_hz``)."""

from __future__ import annotations

import sys
import threading
import time
from typing import Any, TextIO

from ..topics import Update
from .base import Publisher


class ConsolePublisher(Publisher):
    name = "console"

    def __init__(self, options: dict[str, Any] | None = None, out: TextIO | None = None) -> None:
        opts = options or {}
        rate = float(opts.get("rate_hz", 2.0))
        self.period = 1.0 / rate if rate > 0 else 0.0
        self.out = out or sys.stdout
        self._next: dict[str, float] = {}
        self._lock = threading.Lock()

    def publish(self, update: Update) -> None:
        now = time.monotonic()
        name = update.topic.name
        if now < self._next.get(name, 0.0):
            return
        self._next[name] = now + self.period
        unit = update.topic.transducer.unit or ""
        values = " ".join("-" if v is None else str(v) for v in update.values)
        with self._lock:
            print(
                f"{update.stamp_ns / 1e9:.6f} {name} [{values}] {unit}", file=self.out, flush=True
            )

    def diagnostics(self, status: list[dict[str, Any]], now_ns: int) -> None:
        for s in status:
            if s.get("level", 0) >= 2:
                with self._lock:
                    who = s.get("board") or f"publisher {s.get('publisher')}"
                    line = f"{who}: {s.get('state', 'failed')} {s.get('message', '')}"
                    print(
                        f"{now_ns / 1e9:.6f} /diagnostics {line}",
                        file=self.out,
                        flush=True,
                    )
