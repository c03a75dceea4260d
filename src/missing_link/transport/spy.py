"""``spy+URL``: hex-dump every byte both ways (to stderr) without touching the application."""

from __future__ import annotations

import sys
import threading
import time
from typing import TextIO

from .base import Transport


def hexdump_lines(data: bytes, width: int = 16) -> list[str]:
    lines = []
    for i in range(0, len(data), width):
        chunk = data[i : i + width]
        text = "".join(chr(b) if 32 <= b < 127 else "." for b in chunk)
        lines.append(f"{i:04x}  {chunk.hex(' '):<{width * 3}} {text}")
    return lines


class SpyTransport(Transport):
    def __init__(self, inner: Transport, out: TextIO | None = None) -> None:
        self.inner = inner
        self.url = "spy+" + inner.url
        self._out = out if out is not None else sys.stderr
        self._lock = threading.Lock()
        self._t0 = time.monotonic()

    def _dump(self, direction: str, data: bytes) -> None:
        stamp = time.monotonic() - self._t0
        with self._lock:
            print(f"{stamp:10.6f} {direction} {len(data)} bytes", file=self._out)
            for line in hexdump_lines(data):
                print("    " + line, file=self._out)
            self._out.flush()

    def read(self, timeout: float | None) -> bytes:
        data = self.inner.read(timeout)
        if data:
            self._dump("RX", data)
        return data

    def write(self, data: bytes) -> None:
        self._dump("TX", data)
        self.inner.write(data)

    def write_frames(self, frames: list[bytes]) -> None:
        for f in frames:
            self._dump("TX", f)
        self.inner.write_frames(frames)

    @property
    def wakes_on_close(self) -> bool:  # type: ignore[override]
        return self.inner.wakes_on_close

    def link_stats(self) -> dict[str, int]:
        return self.inner.link_stats()

    def poke(self) -> None:
        self.inner.poke()

    def close(self) -> None:
        self.inner.close()
