"""What an idle board costs the daemon: CPU (getrusage of the daemon's own process; the boards are
other processes) with N boards that send one update a second, against the same daemon with no
board (the reference, same run), and the clock-sync probe rate it settles at.

    .venv/bin/python bench/bench_idle.py [--boards 4] [--seconds 30]
"""

from __future__ import annotations

import argparse
import resource
import time

from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config
from missing_link.virtual.process import start_board_process, stop_process


def cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def measure(boards: int, seconds: float) -> tuple[float, float]:
    """(% of a core, probes/s per board) over ``seconds`` after a 5 s settle."""
    procs = [
        start_board_process("rate", k, "tcp://127.0.0.1:0", name=f"i{k}", extra=["--rate", "1"])
        for k in range(boards)
    ]
    try:
        with Daemon(Config(boards=[BoardSpec(u) for _, u in procs])) as d:
            assert d.wait_until_up(20)
            time.sleep(5.0)
            ex0 = sum(s.get("sync_exchanges", 0) for s in d.status())
            c0, t0 = cpu_s(), time.monotonic()
            time.sleep(seconds)
            c1, t1 = cpu_s(), time.monotonic()
            ex1 = sum(s.get("sync_exchanges", 0) for s in d.status())
    finally:
        for p, _ in procs:
            stop_process(p)
    return (c1 - c0) / (t1 - t0) * 100, (ex1 - ex0) / (t1 - t0) / max(1, boards)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--boards", type=int, default=4)
    ap.add_argument("--seconds", type=float, default=30.0)
    a = ap.parse_args()
    ref, _ = measure(0, a.seconds)
    busy, probes = measure(a.boards, a.seconds)
    print("| daemon | % of a core | per board | probes/s per board |")
    print("|---|---|---|---|")
    print(f"| no board (reference) | {ref:.2f} | - | - |")
    print(
        f"| {a.boards} idle boards (1 update/s) | {busy:.2f} | {(busy - ref) / a.boards:.2f}"
        f" | {probes:.1f} |"
    )


if __name__ == "__main__":
    main()
