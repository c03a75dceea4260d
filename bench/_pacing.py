"""Pacing for the benchmarks' rate-limited senders (imported by scripts run from bench/)."""

from __future__ import annotations

import time


def pace(target: float) -> None:
    """Wait until ``target`` (perf_counter): sleep most of it, so other threads run (a busy
    loop would hold the GIL and delay them by the interpreter's switch interval), then spin."""
    left = target - time.perf_counter()
    if left > 2e-4:
        time.sleep(left - 1.5e-4)
    while time.perf_counter() < target:
        pass
