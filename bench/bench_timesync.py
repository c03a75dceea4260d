"""Clock synchronisation, measured against the methods of the anchors in the same run.

1. Simulation (``missing_link.virtual.syncsim``): board clocks with offset, 100 ppm skew, rate
   random walk and a slow sinusoid, 1 µs ticks; links ``pty`` (heavy tails, bursts, loss),
   ``usb`` (full speed, 1 ms frames) and ``ftdi`` (921600 Bd UART behind a 1 ms latency timer).
   Every method runs on every (link, seed); errors are taken at 100 Hz sample stamps after a
   10 s warm-up.  Medians over the seeds; ``worst max`` is the largest over all seeds.
2. Real processes: a virtual board in its own process whose clock is a known affine transform
   of the host's CLOCK_MONOTONIC (random offset, +50 ppm), over a pty and over TCP.
   a) the same real exchanges (10 Hz) feed every method; 1 kHz samples are mapped by each;
   b) the daemon itself (its own probe schedule), error of every published sample.
3. Synchronised action: two virtual boards (separate processes, clocks +50 ppm and -30 ppm),
   ``Daemon.trigger_at(T)``; the true host time each board's trigger fired.
4. Whole run (``--only whole``): a board process whose clock has a random offset, ±50-200 ppm,
   a drifting skew and a reset 18 s in; every sample the daemon publishes from 0.5 s after the
   first one, against the truth.  Then the same scenario recorded with 50 Hz probes and replayed
   through our sync and the anchors' methods on the same exchanges (``replay_timesync.py``).

    .venv/bin/python bench/bench_timesync.py [--seeds 20] [--sim-seconds 120] [--seconds 60]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import random
import statistics
import sys
import tempfile
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

import replay_timesync  # (bench/, next to this file)
from _calibration import est_stats
from _whole_run import whole_run
from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config
from missing_link.errors import CallTimeout
from missing_link.host.board import Board
from missing_link.j2a import SifReceived
from missing_link.topics import Update
from missing_link.virtual import syncsim as sim
from missing_link.virtual.clocks import AffineClock
from missing_link.virtual.process import start_board_process, stop_process

TARGETS = {"pty": (5, 15, 50), "usb": (20, 60, 200), "ftdi": (20, 80, 300), "tcp": (5, 15, 50)}


def _one(job: tuple[str, str, int, float]) -> dict[str, Any]:
    method, link, seed, seconds = job
    r = sim.run(method, link, seed, duration_s=seconds)
    return {
        "method": method,
        "link": link,
        "p50": r.pct(50),
        "p99": r.pct(99),
        "max": r.pct(100),
        "back": r.backwards,
        "cov": r.covered,
        "first": r.first_bound_s,
        "settle": r.settle_s,
        "rate": r.exchanges / seconds,
    }


def _med(xs: list[float]) -> float:
    return statistics.median(xs)


def simulation(seeds: int, seconds: float) -> None:
    jobs = [(m, lk, s, seconds) for lk in sim.LINKS for m in sim.METHODS for s in range(seeds)]
    with ProcessPoolExecutor(max_workers=os.cpu_count() or 2) as pool:
        rows = list(pool.map(_one, jobs, chunksize=4))
    print(f"\n## Simulation: {seeds} seeds x {seconds:.0f} s, medians over seeds (µs)\n")
    print("| link | method | p50 | p99 | max | worst max | p99 vs ours | backwards | probes/s |")
    print("|---|---|---|---|---|---|---|---|---|")
    extra = []
    for lk in sim.LINKS:
        ours_p99 = _med(
            [r["p99"] for r in rows if r["link"] == lk and r["method"] == "missing-link"]
        )
        for m in sim.METHODS:
            rs = [r for r in rows if r["link"] == lk and r["method"] == m]
            p99 = _med([r["p99"] for r in rs])
            print(
                f"| {lk} | {m} | {_med([r['p50'] for r in rs]):.1f} | {p99:.1f}"
                f" | {_med([r['max'] for r in rs]):.1f} | {max(r['max'] for r in rs):.1f}"
                f" | {p99 / ours_p99:.1f}x | {sum(r['back'] for r in rs)}"
                f" | {_med([r['rate'] for r in rs]):.1f} |"
            )
            if m == "missing-link":
                extra.append((lk, rs))
    print("\nmissing-link only: bound coverage (worst seed), first bound < 1 ms, settle (< 50 µs)")
    print("\n| link | target p50/p99/max | coverage (min) | first bound (median, max) | settle |")
    print("|---|---|---|---|---|")
    for lk, rs in extra:
        t = TARGETS[lk]
        firsts = [r["first"] for r in rs if r["first"] is not None]
        print(
            f"| {lk} | {t[0]}/{t[1]}/{t[2]} | {min(r['cov'] for r in rs) * 100:.3f} %"
            f" | {_med(firsts) * 1000:.1f} ms, {max(firsts) * 1000:.1f} ms"
            f" | {_med([r['settle'] for r in rs]):.2f} s |"
        )


# ---- real processes ----------------------------------------------------------------------------
def _board(listen: str, seed: int, skew_ppm: float, sim_name: str = "rate", rate: float = 1000):
    rng = random.Random(seed)
    offset = rng.uniform(1e6, 1e9)
    extra = ["--clock-offset-us", repr(offset), "--clock-skew-ppm", repr(skew_ppm)]
    if sim_name == "rate":
        extra += ["--rate", str(rate)]
    proc, url = start_board_process(sim_name, seed, listen, extra=extra, name=f"b{seed}")
    return proc, url, AffineClock(offset, skew_ppm)


#: every how many exchanges each method takes one (its own probe rate at 10 Hz exchanges)
EVERY = {"missing-link": 1, "px4": 1, "cristian": 10, "rosserial": 25}


def real_same_exchanges(link: str, seconds: float) -> list[str]:
    proc, url, truth = _board("pty" if link == "pty" else "tcp://127.0.0.1:0", 11, 50.0)
    methods = {name: sim.METHODS[name]() for name in sim.METHODS}
    errors: dict[str, list[float]] = {m: [] for m in methods}
    back = dict.fromkeys(methods, 0)
    last: dict[str, float] = {}
    cover = [0, 0]  # (within the bound, with a bound)
    lock = threading.Lock()
    t_start = time.monotonic()
    try:
        with Board.open(url) as board:

            def on_sif(sif: SifReceived, now: float) -> None:
                b = int.from_bytes(sif.payload[:8], "little")
                true_ns = truth.host_ns(b)
                warm = now - t_start > 10
                with lock:
                    for name, m in methods.items():
                        got = m.map(b)
                        if got is None:
                            continue
                        h, bound = got
                        if name in last and h < last[name]:
                            back[name] += 1
                        last[name] = h
                        if warm:
                            errors[name].append(h - true_ns)
                            if bound is not None:
                                cover[1] += 1
                                cover[0] += abs(h - true_ns) <= bound

            board.on_sif(None, on_sif)
            _probe(board, methods, lock, seconds)
    finally:
        stop_process(proc)
    return _same_exchanges_rows(link, errors, back, cover)


def _probe(board: Board, methods: dict[str, Any], lock: threading.Lock, seconds: float) -> None:
    """Clock exchanges at about 10 Hz, each handed to the methods that take it."""
    k = 0
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        now = time.monotonic()
        try:
            ex = board.clock_exchange(1.0)
        except CallTimeout:
            continue
        with lock:
            for name, m in methods.items():
                if k % EVERY[name] == 0:
                    m.on_exchange(ex, now)
        k += 1
        time.sleep(0.1 * random.uniform(0.75, 1.25))


def _same_exchanges_rows(
    link: str, errors: dict[str, list[float]], back: dict[str, int], cover: list[int]
) -> list[str]:
    out = []
    ours = float(np.percentile(np.abs(errors["missing-link"]), 99))
    for name in errors:
        e = np.abs(np.array(errors[name])) / 1000
        cov = f"{cover[0] / cover[1] * 100:.3f} %" if name == "missing-link" and cover[1] else "-"
        out.append(
            f"| {link} | {name} (same exchanges) | {np.percentile(e, 50):.1f}"
            f" | {np.percentile(e, 99):.1f} | {e.max():.1f}"
            f" | {np.percentile(e, 99) * 1000 / ours:.1f}x | {back[name]} | {cov} | {len(e)} |"
        )
    return out


def real_daemon(link: str, seconds: float, seed: int = 12) -> tuple[str, np.ndarray, np.ndarray]:
    """The daemon's own row; and every sample's signed error and estimated error (µs)."""
    skew = (50.0, -120.0, 180.0)[(seed - 12) % 3]
    proc, url, truth = _board("pty" if link == "pty" else "tcp://127.0.0.1:0", seed, skew)
    errs: list[float] = []
    ests: list[float] = []
    state = {"prev": 0, "back": 0, "in": 0, "n": 0}
    try:
        with Daemon(Config(boards=[BoardSpec(url)])) as d:
            assert d.wait_until_up(10)
            t0 = time.monotonic()
            off = d.realtime_offset_ns

            def on_update(u: Update) -> None:
                h = u.host_ns[0]
                if h < state["prev"]:
                    state["back"] += 1
                state["prev"] = h
                err = h - off - truth.host_ns(u.board_us[0])
                state["n"] += 1
                state["in"] += u.bound_ns >= 0 and abs(err) <= u.bound_ns
                if time.monotonic() - t0 > 10 and u.bound_ns >= 0:
                    errs.append(err)
                    ests.append(u.est_error_ns)

            d.subscribe(f"/b{seed}/signal", on_update)
            time.sleep(seconds)
            st = d.status()[0]
    finally:
        stop_process(proc)
    signed = np.array(errs) / 1000
    e = np.abs(signed)
    p50, p99 = np.percentile(e, 50), np.percentile(e, 99)
    cov = state["in"] / state["n"] * 100
    row = (
        f"| {link} | missing-link (daemon) | {p50:.1f} | {p99:.1f} | {e.max():.1f} | -"
        f" | {state['back']} | {cov:.3f} % | {len(e)} |"
        f"\n\n{link} daemon: first bound {st.get('first_bound_ms')} ms,"
        f" probes {st['sync_exchanges']} in {seconds:.0f} s, bound now ±{st.get('bound_us')} µs,"
        f" min RTT {st['sync_min_rtt_us']} µs"
    )
    return row, signed, np.array(ests) / 1000


def _estimate_table(runs: dict[str, list[tuple[np.ndarray, np.ndarray]]], seconds: float) -> None:
    """The daemon's estimated error against the truth, pooled over board seeds (per seed in
    brackets)."""
    print(f"\nThe daemon's estimated error, {len(next(iter(runs.values())))} board seeds x")
    print(f"{seconds:.0f} s per link (skews +50, -120, +180 ppm), every sample after 10 s:\n")
    print("| link | p50 µs | mean signed µs | est_error p50 µs | est / error | within 2 est |")
    print("|---|---|---|---|---|---|")
    for link, rs in runs.items():
        per = [est_stats(np.abs(s), e) for s, e in rs]
        pooled = est_stats(
            np.abs(np.concatenate([s for s, _ in rs])), np.concatenate([e for _, e in rs])
        )
        signed = np.concatenate([s for s, _ in rs])
        ratios = ", ".join(f"{p['est_ratio']:.2f}" for p in per)
        within = ", ".join(f"{p['in_2est']:.1f}" for p in per)
        means = ", ".join(f"{s.mean():+.1f}" for s, _ in rs)
        print(
            f"| {link} | {np.median(np.abs(signed)):.1f} | {signed.mean():+.2f} ({means})"
            f" | {pooled['est_p50']:.1f} | {pooled['est_ratio']:.2f} ({ratios})"
            f" | {pooled['in_2est']:.1f} % ({within}) |"
        )


def whole_runs(seeds: int, seconds: float) -> None:
    print(f"\n## Whole run (from 0.5 s after the first sample), {seeds} seeds x {seconds:.0f} s")
    print("board clock: random offset, +-50..200 ppm, drift +-0.5 ppm/s, reset at 18 s (100 ms")
    print("boot gap), 500 Hz; medians over seeds, worst = max over seeds\n")
    print(
        "| link | p50 µs | p99 µs | max µs (worst) | mean signed µs (seeds) | bound p50 µs"
        " | in bound | est_error p50 µs | est / error (seeds) | within 2 est (seeds)"
        " | not increasing | recovery ms (worst) | probes/s |"
    )
    print("|---" * 13 + "|")
    for link in ("pty", "tcp"):
        rs = [whole_run(link, seconds, 100 + k) for k in range(seeds)]
        med = {k: statistics.median(r[k] for r in rs) for k in rs[0] if k[-3:] != "_us"}
        # pooled over the seeds: every sample of every run counts once
        pooled = est_stats(
            np.concatenate([r["err_us"] for r in rs]), np.concatenate([r["est_us"] for r in rs])
        )
        mean = float(np.concatenate([r["signed_us"] for r in rs]).mean())

        def span(key: str, fmt: str, rs: list[dict[str, Any]] = rs) -> str:
            return f"{min(r[key] for r in rs):{fmt}}..{max(r[key] for r in rs):{fmt}}"

        print(
            f"| {link} | {med['p50']:.1f} | {med['p99']:.1f} | {med['max']:.1f}"
            f" ({max(r['max'] for r in rs):.1f}) | {mean:+.2f} ({span('mean_signed', '+.1f')})"
            f" | {med['bound_p50']:.1f} | {min(r['covered'] for r in rs):.2f} %"
            f" | {pooled['est_p50']:.1f} | {pooled['est_ratio']:.2f} ({span('est_ratio', '.2f')})"
            f" | {pooled['in_2est']:.1f} % ({span('in_2est', '.1f')})"
            f" | {sum(r['not_increasing'] for r in rs)}"
            f" | {med['recovery_ms']:.0f} ({max(r['recovery_ms'] for r in rs):.0f})"
            f" | {med['probes_per_s']:.1f} |",
            flush=True,
        )
    # The anchors on the same scenario: their fixed schedules need exchanges at their own
    # rates, so the runs are recorded with 50 Hz probing and every method (ours on its own
    # schedule too) is replayed on the very same exchanges.
    print(f"\nThe same scenario recorded with 50 Hz probes ({seeds} runs), every method replayed")
    print("on the same exchanges at its own probe rate (bench/replay_timesync.py):\n")
    with tempfile.TemporaryDirectory() as where:
        with contextlib.redirect_stdout(io.StringIO()):
            replay_timesync.record(seeds, seconds, Path(where))
        replay_timesync.replay(Path(where), ["default"], anchors=True)


def trigger(repeats: int) -> None:
    boards = [_board("pty", 21, 50.0, "rangers"), _board("pty", 22, -30.0, "rangers")]
    fired: dict[str, list[tuple[int, int]]] = {"b21": [], "b22": []}
    try:
        cfg = Config(boards=[BoardSpec(url) for _, url, _ in boards])
        with Daemon(cfg) as d:
            assert d.wait_until_up(10)
            for name in fired:
                d.subscribe(
                    f"/{name}/trigger", lambda u, n=name: fired[n].append((u.board_us[0], 0))
                )
            time.sleep(5)  # converge
            targets = []
            ticks = []
            for _ in range(repeats):
                t = time.time_ns() + 300_000_000
                targets.append(t - d.realtime_offset_ns)
                ticks.append(d.trigger_at(t))
                time.sleep(0.5)
            time.sleep(0.5)
    finally:
        for p, _, _ in boards:
            stop_process(p)
    truth = {"b21": boards[0][2], "b22": boards[1][2]}
    spread_fire, spread_tick, late = [], [], []
    for i, target in enumerate(targets):
        a = truth["b21"].host_ns(fired["b21"][i][0])
        b = truth["b22"].host_ns(fired["b22"][i][0])
        spread_fire.append(abs(a - b) / 1000)
        ta = truth["b21"].host_ns(ticks[i]["b21"])
        tb = truth["b22"].host_ns(ticks[i]["b22"])
        spread_tick.append(abs(ta - tb) / 1000)
        late += [(a - target) / 1000, (b - target) / 1000]
    print(f"\n## Synchronised trigger, two board processes over ptys, {repeats} triggers\n")
    print("| measure | median | max |")
    print("|---|---|---|")
    print(
        f"| spread of the chosen board ticks, in true host time (sync only) | "
        f"{_med(spread_tick):.1f} µs | {max(spread_tick):.1f} µs |"
    )
    print(
        f"| spread of the moments the triggers fired (incl. board wake-up) | "
        f"{_med(spread_fire):.1f} µs | {max(spread_fire):.1f} µs |"
    )
    print(
        f"| fire time - requested host time (virtual board wake-up lateness) | "
        f"{_med(late):.1f} µs | {max(late):.1f} µs |"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--sim-seconds", type=float, default=120.0)
    ap.add_argument("--seconds", type=float, default=60.0, help="each real-process run")
    ap.add_argument("--triggers", type=int, default=20)
    ap.add_argument("--whole-seeds", type=int, default=5)
    ap.add_argument("--whole-seconds", type=float, default=30.0)
    ap.add_argument("--only", choices=["sim", "real", "whole", "trigger"], action="append")
    a = ap.parse_args()
    parts = a.only or ["sim", "real", "whole", "trigger"]
    if "whole" in parts:
        whole_runs(a.whole_seeds, a.whole_seconds)
    if "sim" in parts:
        simulation(a.seeds, a.sim_seconds)
    if "real" in parts:
        print(f"\n## Real processes, board clock = offset + (1 + 50 ppm) x host, {a.seconds:.0f} s")
        print("(errors after 10 s; the same-exchange rows share one 10 Hz exchange stream)\n")
        print(
            "| link | method | p50 µs | p99 µs | max µs | p99 vs ours | backwards | in bound | n |"
        )
        print("|---|---|---|---|---|---|---|---|---|")
        notes = []
        more: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
        for link in ("pty", "tcp"):
            for row in real_same_exchanges(link, a.seconds):
                print(row, flush=True)
            text, signed, est = real_daemon(link, a.seconds)
            row, note = text.split("\n\n")
            print(row, flush=True)
            notes.append(note)
            more[link] = [(signed, est)] + [real_daemon(link, a.seconds, s)[1:] for s in (13, 14)]
        print()
        for n in notes:
            print(n)
        _estimate_table(more, a.seconds)
    if "trigger" in parts:
        trigger(a.triggers)


if __name__ == "__main__":
    sys.exit(main())
