"""A load generator for ``bench_scale.py --knee``: many virtual boards in one process and one
thread, fast enough to load the daemon past its knee on a 2-core machine.

    .venv/bin/python bench/_blaster.py --count 64 --rate 1000 [--channels 8] [--cpu 1]

Each board is the real board runtime of ``board --sim rate`` (``missing_link.virtual``): the
handshake, descriptors, clock exchanges and every call are answered by it.  Only the samples are
made here instead of by its driver: a counter per board at an exact rate, stamped with the
board clock (the host's CLOCK_MONOTONIC, as for every virtual board) at its scheduled time, and
framed by the host's J2A encoder (C-level bytes work) rather than the runtime's byte-at-a-time
one.  The runtime numbers every sample made (``next_sif_seq``: the seq and ``a2jSifCount``).

``board --sim rate --count N`` tops out at ~13,000-16,000 updates/s here (a thread and a
runtime pass per sample); this makes well over 100,000/s on one core.  Like a real board, when
the host does not read, samples past a bounded queue are dropped: the host sees the seq gap.
Prints one ``LISTENING tcp://...`` line per board, like ``board --count``."""

from __future__ import annotations

import argparse
import os
import select
import signal
import socket
import struct
import sys
import time

from missing_link.j2a import SOS, encode_frame
from missing_link.virtual import make_sim

QUEUE_LIMIT = 256 * 1024  # bytes of frames a board holds for a host that does not read


class Board:
    def __init__(self, k: int, rate: float, channels: int) -> None:
        self.rt = make_sim("rate", seed=k, name=f"blast_{k}", rate_hz=rate, channels=channels)
        self.channels = channels
        self.pack = struct.Struct("<" + "Qi" * channels).pack
        self.period_us = 1e6 / rate
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.listener.setblocking(False)
        self.conn: socket.socket | None = None
        self.out = bytearray()
        self.start_us = 0
        self.made = 0
        self.dropped = 0

    @property
    def url(self) -> str:
        return f"tcp://127.0.0.1:{self.listener.getsockname()[1]}"

    def accept(self, now_us: int) -> None:
        # (one host at a time, like every virtual board: the listener is not watched while a
        # host is connected, so a second one waits in the backlog)
        conn, _ = self.listener.accept()
        conn.setblocking(False)
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.conn, self.out = conn, bytearray()
        self.start_us, self.made = now_us, 0

    def receive(self) -> None:
        assert self.conn is not None
        try:
            data = self.conn.recv(4096)
        except BlockingIOError:
            return
        except OSError:
            data = b""
        if not data:
            self.conn.close()
            self.conn = None
            return
        rt = self.rt
        rt.feed(data, rx_us=rt.clock())
        self.out += rt.take_output()  # replies (this runtime makes no samples of its own)

    def make_samples(self, now_us: int) -> None:
        period_us = self.period_us
        due = int((now_us - self.start_us) / period_us) + 1  # sample i is due at its stamp
        rt = self.rt
        for i in range(self.made, due):
            n = (i + 1) & 0x7FFFFFFF
            stamp = self.start_us + int(i * period_us)
            seq = rt.next_sif_seq()
            if len(self.out) > QUEUE_LIMIT:
                self.dropped += 1  # (the host sees the gap in the seq)
                continue
            self.out += encode_frame(SOS, seq, 0, self.pack(*((stamp, n) * self.channels)))
        self.made = max(self.made, due)

    def flush(self) -> None:
        if self.conn is None or not self.out:
            return
        try:
            sent = self.conn.send(self.out)
        except BlockingIOError:
            return
        except OSError:
            self.conn.close()
            self.conn = None
            return
        del self.out[:sent]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--count", type=int, default=64)
    ap.add_argument("--rate", type=float, default=1000.0, help="updates/s per board")
    ap.add_argument("--channels", type=int, default=8)
    ap.add_argument("--cpu", type=int, default=None, help="run on this CPU only")
    a = ap.parse_args()
    if a.cpu is not None:
        os.sched_setaffinity(0, {a.cpu})
    boards = [Board(k, a.rate, a.channels) for k in range(a.count)]
    for b in boards:
        print(f"LISTENING {b.url}", flush=True)
    running = True

    def stop(signum: int, frame: object) -> None:
        nonlocal running
        running = False

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    by_sock: dict[socket.socket, Board] = {}
    while running:
        by_sock.clear()
        for b in boards:
            by_sock[b.conn if b.conn is not None else b.listener] = b
        readable, _, _ = select.select(list(by_sock), [], [], 0.001)
        now_us = time.monotonic_ns() // 1000
        for s in readable:
            b = by_sock[s]
            if s is b.listener:
                b.accept(now_us)
            else:
                b.receive()
        for b in boards:
            if b.conn is not None:
                b.make_samples(now_us)
                b.flush()
    dropped = sum(b.dropped for b in boards)
    if dropped:
        print(f"_blaster: {dropped} samples dropped (a host did not read)", file=sys.stderr)
    for b in boards:
        if b.conn is not None:
            b.conn.close()
        b.listener.close()


if __name__ == "__main__":
    main()
