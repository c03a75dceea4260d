"""The AVR rover's sample timing with its world and without (issue 47.6: "the timing tests show
the same figures"): rover-mega.py in simavr as `missing-link board --file --runtime avr`, at
rest, with its world 1 m from its wall (bench_world.py's NEAR_WALL) and with `--world none`
(the reference, in the same run, the cases alternating), a daemon taking its IMU's samples
(50 Hz).  Per case, over the rounds: the periods between two samples' board stamps (the AVR's
own clock, simavr's cycles) as mean, median, the 10th and 90th percentile, shortest, longest
and the share within 1 ms of 20 ms.  simavr is paced to the host's clock, so the host's traffic
reaches the firmware at moments the host's load decides: a figure here is this machine's at
this load, not a statement about the firmware alone (tests/test_world_beside.py holds the
AVR's memory the same; its timing is not held in a test).

    .venv/bin/python bench/bench_world_timing.py [--seconds 6] [--rounds 2]
"""

from __future__ import annotations

import argparse
import itertools
import statistics
import time

from bench_world import start
from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config
from missing_link.topics import Update


def periods(world: bool, seconds: float) -> list[int]:
    """The IMU's sample periods (board µs) over ``seconds``, after 2 s to settle."""
    proc, url = start("avr", world)
    imu: list[Update] = []
    try:
        with Daemon(Config(boards=[BoardSpec(url, timeout=3.0, handshake_timeout=20.0)])) as d:
            if not d.wait_until_up(60):
                raise SystemExit(f"no daemon on the AVR rover: {d.status()}")
            d.subscribe("/mega_rover/imu", imu.append, queue=0)  # (rover-mega.py's name)
            time.sleep(2.0)
            n0, t0 = len(imu), time.monotonic()
            while time.monotonic() - t0 < seconds:
                time.sleep(0.5)
            got = imu[n0:]
    finally:
        proc.terminate()
        proc.wait(15)
    return [b.board_us[0] - a.board_us[0] for a, b in itertools.pairwise(got)]


def row(what: str, p: list[int]) -> str:
    q = sorted(p)
    near = sum(abs(x - 20000) <= 1000 for x in p) / len(p) * 100
    cut = f"{q[len(q) // 10]} | {q[9 * len(q) // 10]} | {q[0]} | {q[-1]}"
    mid = f"{statistics.fmean(p):.1f} | {statistics.median(p):.0f}"
    return f"| {what} | {len(p)} | {mid} | {cut} | {near:.1f} |"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=6.0)
    ap.add_argument("--rounds", type=int, default=2)
    a = ap.parse_args()
    got: dict[bool, list[int]] = {False: [], True: []}
    for _ in range(a.rounds):  # (alternating: a load that comes and goes hits both alike)
        for world in (False, True):
            got[world] += periods(world, a.seconds)
    print("| AVR rover, at rest | periods | mean, µs | median | 10 % | 90 % | shortest | longest "
          "| within 1 ms of 20 ms, % |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|")
    print(row("--world none (reference)", got[False]))
    print(row("its world", got[True]))


if __name__ == "__main__":
    main()
