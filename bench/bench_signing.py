"""What a receiver of signed J2A records (board/signing.py) pays for bytes that are not good
records: the work of a Verifier fed garbage, against the reference of hashing the same bytes
once with the same HMAC, measured in the same run.

    .venv/bin/python bench/bench_signing.py [--kib 256]

Three kinds of garbage, each ``--kib`` KiB:
  random      random bytes (no record magic but by chance);
  headers     record headers back to back, each claiming 4,096 bytes of data (a receiver that
              hashes a claimed record and then steps one byte on hashes ~4 KB per 13 bytes);
  records     whole records of 4,096 bytes with a wrong tag.
Each time is the best of three.  ``ratio`` is the Verifier's time over the reference's: how
many times the HMAC work of one pass over the bytes a receiver spends per byte of garbage.
Run on CPython; the same code runs on MicroPython (not measured there).
"""

from __future__ import annotations

import argparse
import random
import struct
import time

from missing_link.board.signing import HOST_LINK, MAGIC, MAX_DATA, Verifier, hmac_sha256

KEY = bytes(range(32))


def garbage(kind: str, size: int, rng: random.Random) -> bytes:
    if kind == "random":
        return rng.randbytes(size)
    head = MAGIC + bytes((HOST_LINK,)) + bytes(6) + struct.pack("<H", MAX_DATA)
    if kind == "headers":
        return (head * (size // len(head) + 1))[:size]
    record = head + rng.randbytes(MAX_DATA) + bytes(8)
    return (record * (size // len(record) + 1))[:size]


def reference(data: bytes) -> float:
    """One HMAC pass over the bytes, in records of MAX_DATA: the least a receiver does."""
    t = time.perf_counter()
    for i in range(0, len(data), MAX_DATA):
        hmac_sha256(KEY, data[i : i + MAX_DATA])
    return time.perf_counter() - t


def verify(data: bytes, chunk: int = 512) -> tuple[float, dict[str, int]]:
    v = Verifier(KEY, HOST_LINK)
    t = time.perf_counter()
    for i in range(0, len(data), chunk):  # (as a socket delivers it)
        v.feed(data[i : i + chunk])
    return time.perf_counter() - t, v.stats()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--kib", type=int, default=256)
    args = ap.parse_args()
    rng = random.Random(1)
    head = f"{'garbage':<10} {'KiB':>5} {'reference ms':>13} {'verifier ms':>12} {'ratio':>7}"
    print(head + "  counted")
    for kind in ("random", "headers", "records"):
        data = garbage(kind, args.kib * 1024, rng)
        ref = min(reference(data) for _ in range(3))
        runs = [verify(data) for _ in range(3)]
        took, stats = min(r[0] for r in runs), runs[0][1]
        counted = ", ".join(f"{k} {v}" for k, v in stats.items() if v)
        print(
            f"{kind:<10} {args.kib:>5} {ref * 1e3:>13.1f} {took * 1e3:>12.1f} "
            f"{took / ref:>7.1f}  {counted}"
        )


if __name__ == "__main__":
    main()
