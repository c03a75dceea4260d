"""RPC round trips per second: a2jEcho with 0 and 255 bytes between two processes, over a real
pseudo-terminal and over TCP loopback.  Reference, same run, same link: a raw echo process that
sends the same bytes straight back (no J2A on either side) - the floor set by the link and by
two Python processes taking turns.

    .venv/bin/python bench/bench_rpc.py [--seconds 2]
"""

from __future__ import annotations

import argparse
import os
import select
import socket
import statistics
import subprocess
import sys
import time
import tty

from missing_link import open_board
from missing_link.j2a import SOF, encode_frame
from missing_link.virtual.process import start_board_process, stop_process

ECHO_PEER = r"""
import os, select, socket, sys, tty
kind = sys.argv[1]
if kind == "pty":
    master, slave = os.openpty(); tty.setraw(slave); tty.setraw(master)
    print("LISTENING", os.ttyname(slave), flush=True)
    fd_r = fd_w = master
    while True:
        data = os.read(fd_r, 4096)
        os.write(fd_w, data)
else:
    s = socket.socket(); s.bind(("127.0.0.1", 0)); s.listen(1)
    print("LISTENING", s.getsockname()[1], flush=True)
    c, _ = s.accept(); c.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    while True:
        data = c.recv(4096)
        if not data: break
        c.sendall(data)
"""


def raw_echo_rate(kind: str, frame: bytes, seconds: float) -> tuple[float, float]:
    proc = subprocess.Popen(
        [sys.executable, "-c", ECHO_PEER, kind], stdout=subprocess.PIPE, text=True
    )
    assert proc.stdout is not None
    where = proc.stdout.readline().split()[1]
    try:
        if kind == "pty":
            fd = os.open(where, os.O_RDWR | os.O_NOCTTY)
            tty.setraw(fd)
            send, recv = (lambda b: os.write(fd, b)), (lambda: os.read(fd, 4096))
        else:
            sock = socket.create_connection(("127.0.0.1", int(where)))
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            fd = sock.fileno()
            send, recv = sock.send, (lambda: sock.recv(4096))
        rtts = []
        t_end = time.perf_counter() + seconds
        while time.perf_counter() < t_end:
            t0 = time.perf_counter()
            send(frame)
            got = 0
            while got < len(frame):
                select.select([fd], [], [], 1.0)
                got += len(recv())
            rtts.append(time.perf_counter() - t0)
        return len(rtts) / sum(rtts), statistics.median(rtts) * 1e6
    finally:
        proc.kill()
        proc.wait()


def j2a_rate(url: str, payload: bytes, seconds: float) -> tuple[float, float]:
    with open_board(url) as board:
        for _ in range(50):
            board.call("a2jEcho", payload)
        rtts = []
        t_end = time.perf_counter() + seconds
        while time.perf_counter() < t_end:
            t0 = time.perf_counter()
            board.call("a2jEcho", payload)
            rtts.append(time.perf_counter() - t0)
    return len(rtts) / sum(rtts), statistics.median(rtts) * 1e6


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=2.0)
    args = ap.parse_args()
    print(
        "a2jEcho round trips between two processes; the virtual board (sim 'original') keeps "
        "pushing its encoder's ~1 kHz sample SIFs meanwhile, as a real board would"
    )
    head = (
        f"{'link':<5} {'payload':>7} | {'J2A calls/s':>11} {'p50 RTT':>9} |"
        f" {'raw echo/s':>10} {'p50 RTT':>9} | {'J2A/raw':>7}"
    )
    print(head)
    print("-" * len(head))
    for kind in ("pty", "tcp"):
        listen = "pty" if kind == "pty" else "tcp://127.0.0.1:0"
        proc, url = start_board_process("original", 0, listen)
        try:
            for size in (0, 255):
                payload = bytes((i * 37) & 0xFF for i in range(size))
                rate, p50 = j2a_rate(url, payload, args.seconds)
                frame = encode_frame(SOF, 1, 4, payload)
                raw_rate, raw_p50 = raw_echo_rate(kind, frame, args.seconds)
                print(
                    f"{kind:<5} {size:>7} | {rate:>11,.0f} {p50:>7.0f}us | {raw_rate:>10,.0f}"
                    f" {raw_p50:>7.0f}us | {rate / raw_rate:>6.0%}"
                )
        finally:
            stop_process(proc)
    return 0


if __name__ == "__main__":
    sys.exit(main())
