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
from dataclasses import dataclass, field
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


@dataclass
class Run:
    """What one run saw: samples by phase, the triggers' reports, what was asked."""

    clocks: dict[str, AffineClock]
    samples: dict[str, list[tuple[str, int]]]  #: per board: (phase, board µs)
    fired: dict[str, list[int]]  #: per board: board µs of each trigger it reported
    asked: list[int] = field(default_factory=list)  #: realtime ns the triggers were asked for
    refused: int = 0
    status: dict[str, dict[str, Any]] = field(default_factory=dict)
    off: int = 0  #: the daemon's realtime - monotonic offset

    def true_rt(self, name: str, board_us: int) -> float:
        return self.clocks[name].host_ns(board_us) + self.off


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
    run = Run({n: c for n, (_p, _u, c) in boards.items()}, {n: [] for n in boards},
              {n: [] for n in boards})  # fmt: skip
    try:
        measure(run, [url for _p, url, _c in boards.values()], a.free_seconds, a.seconds)
    finally:
        for p, _u, _c in boards.values():
            stop_process(p)
    report(run, a.link, a.free_seconds, a.seconds)
    return 0


def measure(run: Run, urls: list[str], free_s: float, aligned_s: float) -> None:
    """Free running, then aligned with timed triggers every half second."""
    phase = {"now": "settle"}

    def on_sample(name: str) -> Any:
        def keep(u: Any) -> None:
            if phase["now"] != "settle":
                run.samples[name].append((phase["now"], u.board_us[0]))

        return keep

    with Daemon(Config(boards=[BoardSpec(url) for url in urls])) as d:
        assert d.wait_until_up(15), d.status()
        run.off = d.realtime_offset_ns
        for n in run.clocks:
            d.subscribe(f"/{n}/signal", on_sample(n), queue=0)
            d.subscribe(f"/{n}/trigger", lambda u, n=n: run.fired[n].append(u.board_us[0]), queue=0)
        time.sleep(3.0)  # the clock maps settle
        phase["now"] = "free"
        time.sleep(free_s)
        phase["now"] = "settle"
        for n in run.clocks:
            d.configure(n, {"signal.aligned": True, "signal.rate_hz": 50})
        time.sleep(1.0)
        phase["now"] = "aligned"
        end = time.monotonic() + aligned_s
        while time.monotonic() < end:
            at = time.time_ns() + 250_000_000
            for n in run.clocks:
                try:
                    d.send(f"/{n}/trigger/cmd", 10, at_ns=at)
                except Exception as e:  # noqa: BLE001 - a refusal is counted and shown
                    run.refused += 1
                    print(f"{n}: trigger refused: {e}", file=sys.stderr)
            run.asked.append(at)
            time.sleep(0.5)
        time.sleep(0.5)
        run.status = {s["board"]: s for s in d.status()}


def _on_grid(run: Run, name: str, kind: str) -> dict[int, float]:
    """True realtime of ``name``'s samples in phase ``kind``, by grid index."""
    out = {}
    for ph, b in run.samples[name]:
        if ph == kind:
            t = run.true_rt(name, b)
            out[round(t / PERIOD_NS)] = t
    return out


def _free_running(run: Run) -> tuple[list[float], list[float]]:
    """(a1's samples' distance to a2's nearest, a1's samples' distance from the grid) in µs."""
    free1 = np.array(sorted(run.true_rt("a1", b) for ph, b in run.samples["a1"] if ph == "free"))
    free2 = np.array(sorted(run.true_rt("a2", b) for ph, b in run.samples["a2"] if ph == "free"))
    nearest = []
    for t in free1:
        i = np.searchsorted(free2, t)
        cands = [free2[j] for j in (i - 1, i) if 0 <= j < len(free2)]
        if cands:
            nearest.append(min(abs(t - c) for c in cands) / 1000)
    return nearest, [(t - round(t / PERIOD_NS) * PERIOD_NS) / 1000 for t in free1]


def _triggers(run: Run) -> tuple[list[float], list[float]]:
    """(acted - asked per trigger, the two boards apart per trigger) in µs."""
    trig: list[float] = []
    spread: list[float] = []
    for k, at in enumerate(run.asked):
        acted = {}
        for n in run.clocks:
            if k < len(run.fired[n]):
                acted[n] = run.true_rt(n, run.fired[n][k])
                trig.append((acted[n] - at) / 1000)
        if len(acted) == 2:
            spread.append((acted["a1"] - acted["a2"]) / 1000)
    return trig, spread


def report(run: Run, link: str, free_s: float, aligned_s: float) -> None:
    g1, g2 = _on_grid(run, "a1", "aligned"), _on_grid(run, "a2", "aligned")
    pair_us = [(g1[k] - g2[k]) / 1000 for k in sorted(set(g1) & set(g2))]
    grid_us = [(t - round(t / PERIOD_NS) * PERIOD_NS) / 1000 for t in [*g1.values(), *g2.values()]]
    nearest, free_grid = _free_running(run)
    trig, spread = _triggers(run)
    print(f"\n## Aligned sampling and timed triggers, two boards over {link} (+150 / -150 ppm)")
    print(f"free running {free_s:.0f} s, then aligned at 50 Hz for {aligned_s:.0f} s\n")
    print("| measure (true host time) | p50 µs | p99 µs | max µs | n |")
    print("|---|---|---|---|---|")
    print(f"| free running (reference): nearest samples of the two boards | {pct(nearest)} |")
    print(f"| free running (reference): a sample's distance from the grid | {pct(free_grid)} |")
    print(f"| aligned: the two boards' samples with the same grid index | {pct(pair_us)} |")
    print(f"| aligned: a sample's distance from the grid | {pct(grid_us)} |")
    print(f"| timed trigger: acted - asked | {pct(trig)} |")
    print(f"| timed trigger: the two boards apart | {pct(spread)} |")
    for n, s in run.status.items():
        print(
            f"\n{n}: map age {s.get('map_age_ms')} ms, samples without a valid map "
            f"{s.get('unaligned_samples')}, off the grid (host check) {s.get('off_grid_samples')},"
            f" timed calls done {s.get('timed_done')}, refused {s.get('timed_refused')}"
        )
    missing = len(run.asked) * 2 - len(trig)
    print(f"\ntriggers asked {len(run.asked) * 2}, acted {len(trig)}, refused {run.refused}, "
          f"missing {missing}")  # fmt: skip


if __name__ == "__main__":
    sys.exit(main())
