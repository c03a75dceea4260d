"""J2A codec throughput: encode and decode at payload 8, 64 and 255 bytes, random payloads (3 of
256 byte values are special, so ~1.2 % of bytes need escaping, as on a real link), compared with a
straightforward byte-by-byte reference decoder measured in the same run.

    .venv/bin/python bench/bench_codec.py [--seconds 1.0]
"""

from __future__ import annotations

import argparse
import platform
import random
import sys
import time
from collections.abc import Callable

from missing_link.j2a.codec import SOF, SOS, FrameDecoder, encode_frame

ESC = 0x7D


class ReferenceDecoder:
    """The obvious implementation: one Python-level step per byte (like a C decoder, in Python)."""

    def __init__(self) -> None:
        self.state = 0
        self.esc = False
        self.frames: list[tuple[int, int, int, bytes]] = []

    def feed(self, data: bytes) -> None:
        for b in data:
            if b in (SOF, SOS):
                self.start, self.state, self.esc, self.hdr, self.body = b, 1, False, [], bytearray()
                continue
            if self.state == 0:
                continue
            if self.esc:
                b += 1
                self.esc = False
            elif b == ESC:
                self.esc = True
                continue
            if self.state == 1:
                self.hdr.append(b)
                if len(self.hdr) == 3:
                    self.state = 2
            elif len(self.body) < self.hdr[2]:
                self.body.append(b)
            else:
                seq, op, n = self.hdr
                c = seq ^ ((op + 11) & 0xFF) ^ ((n + 97) & 0xFF)
                for x in self.body:
                    c ^= x
                if c == b:
                    self.frames.append((self.start, seq, op, bytes(self.body)))
                self.state = 0


def make_stream(payload: int, count: int, rng: random.Random) -> tuple[bytes, int]:
    frames = [
        encode_frame(SOS if i % 4 else SOF, i & 0xFF, rng.randrange(240), rng.randbytes(payload))
        for i in range(count)
    ]
    return b"".join(frames), count


def rate(fn: Callable[[], int], seconds: float) -> float:
    """Units per second: repeat fn (which returns units done) for about ``seconds``."""
    done, t0 = 0, time.perf_counter()
    while True:
        done += fn()
        elapsed = time.perf_counter() - t0
        if elapsed >= seconds:
            return done / elapsed


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=1.0, help="time per measurement")
    args = ap.parse_args()
    rng = random.Random(42)
    print(f"J2A codec, {platform.python_implementation()} {platform.python_version()}, one core")
    head = (
        f"{'payload':>7} | {'decode MB/s':>11} {'frames/s':>10} | {'ref MB/s':>8} {'ref fr/s':>9}"
    )
    head += f" | {'speedup':>7} | {'encode fr/s':>11} {'MB/s':>6}"
    print(head)
    print("-" * len(head))
    for payload in (8, 64, 255):
        count = 2000
        stream, n = make_stream(payload, count, rng)
        # Feed in 4 KiB reads, as from a serial port or socket.
        chunks = [stream[i : i + 4096] for i in range(0, len(stream), 4096)]

        def ours(chunks: list[bytes] = chunks, n: int = n) -> int:
            dec = FrameDecoder()
            got = 0
            for c in chunks:
                got += len(dec.feed(c))
            assert got == n
            return n

        def ref(chunks: list[bytes] = chunks, n: int = n) -> int:
            dec = ReferenceDecoder()
            for c in chunks:
                dec.feed(c)
            assert len(dec.frames) == n
            return n

        items = [(SOS, i & 0xFF, 3, rng.randbytes(payload)) for i in range(count)]

        def enc(items: list[tuple[int, int, int, bytes]] = items, count: int = count) -> int:
            for item in items:
                encode_frame(*item)
            return count

        fps = rate(ours, args.seconds)
        ref_fps = rate(ref, args.seconds)
        enc_fps = rate(enc, args.seconds)
        wire = len(stream) / n  # encoded bytes per frame
        print(
            f"{payload:>7} | {fps * wire / 1e6:>11.1f} {fps:>10,.0f} | {ref_fps * wire / 1e6:>8.2f}"
            f" {ref_fps:>9,.0f} | {fps / ref_fps:>6.1f}x | {enc_fps:>11,.0f}"
            f" {enc_fps * wire / 1e6:>6.1f}"
        )
    print("MB/s counts encoded bytes on the wire. USB 2.0 high-speed bulk is ~40 MB/s in practice.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
