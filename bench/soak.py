"""Soak: several boards, faults cycled on each, every sample accounted for; threads, fds, RSS flat.

    .venv/bin/python bench/soak.py --boards 4 --minutes 3

Each board is a real process (``missing-link board --sim rate``: one int32 counter, numbered
1, 2, 3, ... per boot) behind an in-process fault relay.  Every ``--period`` seconds one board
(round robin) gets one fault from the cycle:

  freeze    SIGSTOP for 2 s, then SIGCONT (a hung board; the link stays open)
  blackhole nothing through the relay for 2 s (a half-open link)
  corrupt   one bit in 1,000 bytes flipped both ways for 5 s (a noisy line)
  kill      SIGKILL, then a new process on a new port 1 s later (a reset: new boot, new epoch)

Accounting, per board and boot: consecutive updates received with counters a < b carry the
daemon's ``lost`` count; b - a - 1 samples are missing.  A gap is *counted* when ``lost`` equals
it, *counted mod 256* when it matches modulo 256 (J2A's SIF seq is 8 bit: an outage of over 255
SIFs is undercounted by multiples of 256 -- unless the board answers ``a2jSifCount``, as ours
do), and *silent* otherwise -- which must never happen.
Samples a board sends between the daemon's last read and its SIGKILL die with the process: they
are not a host-side loss and are outside these books (a new boot starts a new count).  The
reference column is the same daemon and boards without faults, measured in the same run.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import Any

from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config
from missing_link.topics import Update
from missing_link.virtual.faults import FaultRelay

FAULTS = ("freeze", "blackhole", "corrupt", "kill")


def start_board(name: str, rate: float) -> tuple[subprocess.Popen[str], str]:
    p = subprocess.Popen(
        [
            *(sys.executable, "-m", "missing_link", "board", "--sim", "rate"),
            *("--rate", str(rate), "--name", name, "--listen", "tcp://127.0.0.1:0"),
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    assert p.stdout is not None
    line = p.stdout.readline()
    if not line.startswith("LISTENING "):
        raise SystemExit(f"board {name} did not start: {line!r}")
    return p, line.split()[1]


@dataclass
class Tally:
    received: int = 0
    counted: int = 0
    counted_mod: int = 0
    silent: int = 0
    boots: int = 1
    last: int | None = None
    lock: threading.Lock = field(default_factory=threading.Lock)

    def on_update(self, u: Update) -> None:
        v = u.values[0]
        with self.lock:
            self.received += 1
            if self.last is not None and v > self.last:
                missing = v - self.last - 1
                if missing == u.lost:
                    self.counted += missing
                elif missing > 0 and (missing - u.lost) % 256 == 0:
                    self.counted_mod += missing
                else:
                    self.silent += max(0, missing - u.lost)
            elif self.last is not None and v <= self.last:
                self.boots += 1  # a new boot counts from 1 again
            self.last = v


def resources() -> tuple[int, int, float]:
    fds = len(os.listdir("/proc/self/fd"))
    rss = 0.0
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                rss = int(line.split()[1]) / 1024
    return threading.active_count(), fds, rss


def run(boards: int, seconds: float, rate: float, period: float, faults: bool) -> dict[str, float]:
    procs: list[subprocess.Popen[str]] = []
    relays: list[FaultRelay] = []
    for k in range(boards):
        p, url = start_board(f"b{k}", rate)
        procs.append(p)
        relays.append(FaultRelay(url).start())
    cfg = Config(boards=[BoardSpec(r.url) for r in relays])
    tallies = [Tally() for _ in range(boards)]
    done = {f: 0 for f in FAULTS}
    with Daemon(cfg) as d:
        if not d.wait_until_up(30):
            raise SystemExit("boards did not come up")
        for k, t in enumerate(tallies):
            d.subscribe(f"/b{k}/signal", t.on_update)
        time.sleep(2.0)
        start_res = resources()
        t0 = time.monotonic()
        step = 0
        while time.monotonic() - t0 < seconds:
            time.sleep(period)
            if not faults:
                continue
            k, fault = step % boards, FAULTS[(step // boards) % len(FAULTS)]
            step += 1
            done[fault] += 1
            inject(fault, k, procs, relays, rate)
        # let every board come back before the books are closed
        d.wait_until_up(30)
        time.sleep(3.0)
        end_res = resources()
        status = d.status()
    for p in procs:
        p.terminate()
        p.wait(10)
    for r in relays:
        r.stop()
    return {
        **books(tallies, status),
        "threads": end_res[0] - start_res[0],
        "fds": end_res[1] - start_res[1],
        "rss_mb": end_res[2] - start_res[2],
        **{f"n_{f}": v for f, v in done.items()},
    }


def inject(
    fault: str, k: int, procs: list[subprocess.Popen[str]], relays: list[FaultRelay], rate: float
) -> None:
    """One fault on board ``k``, and its end."""
    if fault == "freeze":
        procs[k].send_signal(signal.SIGSTOP)
        time.sleep(2.0)
        procs[k].send_signal(signal.SIGCONT)
    elif fault == "blackhole":
        relays[k].blackhole(True)
        time.sleep(2.0)
        relays[k].blackhole(False)
    elif fault == "corrupt":
        relays[k].set_corrupt(1e-3)
        time.sleep(5.0)
        relays[k].set_corrupt(0.0)
    else:
        procs[k].kill()
        procs[k].wait()
        time.sleep(1.0)
        procs[k], relays[k].upstream = start_board(f"b{k}", rate)


def books(tallies: list[Tally], status: list[dict[str, Any]]) -> dict[str, float]:
    """What the subscribers counted, and what the daemon says it dropped and why."""
    return {
        "received": sum(t.received for t in tallies),
        "counted": sum(t.counted for t in tallies),
        "counted_mod256": sum(t.counted_mod for t in tallies),
        "silent": sum(t.silent for t in tallies),
        "boots": sum(t.boots for t in tallies),
        "bad_checksums": sum(s["bad_checksums"] + s["bad_escapes"] for s in status),
        "stale_links": sum(s["stale_links"] for s in status),
        "outage_lost": sum(s["outage_lost_sifs"] for s in status),
        "reconnects": sum(s["connects"] - 1 for s in status),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    ap.add_argument("--boards", type=int, default=4)
    ap.add_argument("--minutes", type=float, default=3.0)
    ap.add_argument("--rate", type=float, default=100.0, help="updates/s per board")
    ap.add_argument("--period", type=float, default=4.0, help="s between faults")
    ap.add_argument("--reference-seconds", type=float, default=30.0)
    a = ap.parse_args()
    ref = run(a.boards, a.reference_seconds, a.rate, a.period, faults=False)
    soak = run(a.boards, a.minutes * 60, a.rate, a.period, faults=True)
    keys = list(soak)
    print(f"soak: {a.boards} boards x {a.rate:g} updates/s, a fault every {a.period:g} s")
    print(f"| {'':>16} | {'reference (no faults)':>22} | {'soak':>12} |")
    print(f"|{'-' * 18}|{'-' * 24}|{'-' * 14}|")
    for k in keys:
        print(f"| {k:>16} | {ref[k]:>22.6g} | {soak[k]:>12.6g} |")
    ok = soak["silent"] == 0 and ref["silent"] == 0
    print("every missing sample counted:", "yes" if ok else "NO")
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()
