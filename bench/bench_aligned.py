"""Measuring together and acting on time, against the truth (board/timing.py; docs/timesync.md).

Two virtual boards in their own processes, over ptys, whose clocks have different offsets and
skews of +150 and -150 ppm (known: their stamps map to true host times), each with a 50 Hz
``signal`` and a ``trigger`` output:

* free running first (the reference: what a fusion node has to interpolate over), then
* ``aligned = true`` on both: every sample should fall on the host-time grid (whole multiples of
  20 ms of CLOCK_REALTIME), so the two boards' samples with the same grid index are taken at the
  same instant;
* timed triggers: every half second both boards are told to pulse at one host time 250 ms ahead
  (``Daemon.send(topic, value, at_ns=...)``); each reports the moment it acted.

    .venv/bin/python bench/bench_aligned.py [--seconds 60] [--free-seconds 20] [--link pty|tcp]

Prints a table: for each measure p50 / p99 / max of the true-time differences (µs), same run."""

from __future__ import annotations

import argparse
import random
import sys
import time
from typing import Any

import numpy as np

from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config
from missing_link.virtual.clocks import AffineClock
from missing_link.virtual.process import start_board_process, stop_process

PERIOD_NS = 20_000_000  # 50 Hz


def board(name: str, seed: int, skew_ppm: float, link: str) -> tuple[Any, str, AffineClock]:
    rng = random.Random(seed)
    offset = rng.uniform(1e6, 1e9)
    extra = ["--clock-offset-us", repr(offset), "--clock-skew-ppm", repr(skew_ppm)]
    listen = "pty" if link == "pty" else "tcp://127.0.0.1:0"
    proc, url = start_board_process("aligned", seed, listen, name=name, extra=extra)
    return proc, url, AffineClock(offset, skew_ppm)


def pct(xs: list[float] | np.ndarray) -> str:
    a = np.abs(np.asarray(xs, dtype=float))
    if not len(a):
        return "- | - | - | 0"
    return f"{np.percentile(a, 50):.1f} | {np.percentile(a, 99):.1f} | {a.max():.1f} | {len(a)}"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="aligned (60)")
    ap.add_argument("--free-seconds", type=float, default=20.0, help="free running first (20)")
    ap.add_argument("--link", choices=("pty", "tcp"), default="pty")
    a = ap.parse_args()
    boards = {
        "a1": board("a1", 31, 150.0, a.link),
        "a2": board("a2", 32, -150.0, a.link),
    }
    samples: dict[str, list[tuple[float, int]]] = {n: [] for n in boards}  # (mono s, board µs)
    fired: dict[str, list[int]] = {n: [] for n in boards}
    asked: list[int] = []  # realtime ns the triggers were asked for
    phase = {"now": "settle"}
    try:
        cfg = Config(boards=[BoardSpec(url) for _p, url, _c in boards.values()])
        with Daemon(cfg) as d:
            assert d.wait_until_up(15), d.status()
            off = d.realtime_offset_ns
            for n in boards:
                d.subscribe(
                    f"/{n}/signal",
                    lambda u, n=n: (
                        samples[n].append((phase["now"], u.board_us[0]))
                        if phase["now"] != "settle"
                        else None
                    ),
                    queue=0,
                )
                d.subscribe(f"/{n}/trigger", lambda u, n=n: fired[n].append(u.board_us[0]), queue=0)
            time.sleep(3.0)  # the clock maps settle
            phase["now"] = "free"
            time.sleep(a.free_seconds)
            phase["now"] = "settle"
            for n in boards:
                d.configure(n, {"signal.aligned": True, "signal.rate_hz": 50})
            time.sleep(1.0)
            phase["now"] = "aligned"
            end = time.monotonic() + a.seconds
            refused = 0
            while time.monotonic() < end:
                at = time.time_ns() + 250_000_000
                for n in boards:
                    try:
                        d.send(f"/{n}/trigger/cmd", 10, at_ns=at)
                    except Exception as e:  # noqa: BLE001 - a refusal is counted and shown
                        refused += 1
                        print(f"{n}: trigger refused: {e}", file=sys.stderr)
                asked.append(at)
                time.sleep(0.5)
            time.sleep(0.5)
            status = {s["board"]: s for s in d.status()}
    finally:
        for p, _u, _c in boards.values():
            stop_process(p)

    def true_rt(name: str, board_us: int) -> float:
        return boards[name][2].host_ns(board_us) + off

    def by_index(name: str, kind: str) -> dict[int, float]:
        out = {}
        for ph, b in samples[name]:
            if ph == kind:
                t = true_rt(name, b)
                out[round(t / PERIOD_NS)] = t
        return out

    g1, g2 = by_index("a1", "aligned"), by_index("a2", "aligned")
    common = sorted(set(g1) & set(g2))
    pair_us = [(g1[k] - g2[k]) / 1000 for k in common]
    grid_us = [(t - round(t / PERIOD_NS) * PERIOD_NS) / 1000 for t in [*g1.values(), *g2.values()]]
    free1 = np.array(sorted(true_rt("a1", b) for ph, b in samples["a1"] if ph == "free"))
    free2 = np.array(sorted(true_rt("a2", b) for ph, b in samples["a2"] if ph == "free"))
    nearest = []
    for t in free1:
        i = np.searchsorted(free2, t)
        cands = [free2[j] for j in (i - 1, i) if 0 <= j < len(free2)]
        if cands:
            nearest.append(min(abs(t - c) for c in cands) / 1000)
    free_grid = [(t - round(t / PERIOD_NS) * PERIOD_NS) / 1000 for t in free1]
    trig: list[float] = []
    spread: list[float] = []
    for k, at in enumerate(asked):
        acted = {}
        for n in boards:
            if k < len(fired[n]):
                acted[n] = true_rt(n, fired[n][k])
                trig.append((acted[n] - at) / 1000)
        if len(acted) == 2:
            spread.append((acted["a1"] - acted["a2"]) / 1000)
    print(f"\n## Aligned sampling and timed triggers, two boards over {a.link} (+150 / -150 ppm)")
    print(f"free running {a.free_seconds:.0f} s, then aligned at 50 Hz for {a.seconds:.0f} s\n")
    print("| measure (true host time) | p50 µs | p99 µs | max µs | n |")
    print("|---|---|---|---|---|")
    print(f"| free running (reference): nearest samples of the two boards | {pct(nearest)} |")
    print(f"| free running (reference): a sample's distance from the grid | {pct(free_grid)} |")
    print(f"| aligned: the two boards' samples with the same grid index | {pct(pair_us)} |")
    print(f"| aligned: a sample's distance from the grid | {pct(grid_us)} |")
    print(f"| timed trigger: acted - asked | {pct(trig)} |")
    print(f"| timed trigger: the two boards apart | {pct(spread)} |")
    for n, s in status.items():
        print(
            f"\n{n}: map age {s.get('map_age_ms')} ms, samples without a valid map "
            f"{s.get('unaligned_samples')}, off the grid (host check) {s.get('off_grid_samples')},"
            f" timed calls done {s.get('timed_done')}, refused {s.get('timed_refused')}"
        )
    missing = len(asked) * 2 - len(trig)
    print(f"\ntriggers asked {len(asked) * 2}, acted {len(trig)}, refused {refused}, "
          f"missing {missing}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
