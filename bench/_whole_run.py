"""The whole-run clock-sync scenario, as a user sees it (``bench_timesync.py --only whole`` runs
it; ``replay_timesync.py`` records it): a board process with a known clock, the daemon, and an
independent check of every sample against that clock."""

from __future__ import annotations

import itertools
import random
import time
from collections.abc import Iterable
from typing import Any

import numpy as np

from _calibration import est_stats
from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config
from missing_link.publishers.base import Publisher
from missing_link.topics import Update
from missing_link.virtual.clocks import DriftClock
from missing_link.virtual.process import start_board_process, stop_process

GAP_MS = 100.0  #: the board's boot gap at its reset

#: (host recv ns, host ns, error ns, bound ns, flags, estimated error ns) per sample
Row = tuple[int, int, float, int, int, int]


def whole_run(
    link: str,
    seconds: float,
    seed: int,
    reset_s: float = 18.0,
    extra_publishers: Iterable[Publisher] = (),
) -> dict[str, Any]:
    """The whole run as a user sees it: an independent check of every sample from 0.5 s after
    the first one, against a board clock with a random offset, skew of +-50..200 ppm, a drift
    of the skew, and one reset (100 ms boot gap) ``reset_s`` in; 500 Hz samples.
    ``extra_publishers`` see what the daemon publishes (the recorder: its clock records).
    Besides the figures, the result has the run's ``truth`` (the board clock),
    ``first_sample_ns``, ``answering_again_ns`` and the daemon's ``realtime_offset_ns``."""
    truth, extra = _board_clock(seed, reset_s)
    listen = "pty" if link == "pty" else "tcp://127.0.0.1:0"
    proc, url = start_board_process("rate", seed, listen, extra=extra, name="w")
    answering_again = truth.reset_ns[0] + GAP_MS * 1e6
    rows: list[Row] = []
    try:
        with Daemon(Config(boards=[BoardSpec(url)]), extra_publishers=extra_publishers) as d:
            off = d.realtime_offset_ns

            def on_update(u: Update) -> None:
                boot = 0 if u.recv_ns < answering_again else 1
                true_ns = truth.host_ns(u.board_us[0], boot)
                h = u.host_ns[0]
                rows.append(
                    (u.recv_ns, h, h - off - true_ns, u.bound_ns, u.clock_flags, u.est_error_ns)
                )

            d.subscribe("/w/signal", on_update, queue=0)
            # ``seconds`` of the board's clock, and at least a second of samples: on a busy
            # machine the board process and the daemon's first map can take most of a short
            # run (then there was nothing 0.5 s after the first sample to check)
            t_end = truth.ref_ns + seconds * 1e9
            give_up = time.monotonic_ns() + (seconds + 120) * 1e9  # (bounded, whatever)
            while time.monotonic_ns() < t_end or (
                (not rows or rows[-1][0] < rows[0][0] + 1e9) and time.monotonic_ns() < give_up
            ):
                time.sleep(0.2)
            st = d.status()[0]
    finally:
        stop_process(proc)
    return {
        **_figures(rows, answering_again),
        "probes_per_s": st["sync_exchanges"] / seconds,
        "resets": st["sync_resets"],
        "lost": st["sync_lost"],
        "interval_ms": st["sync_interval_ms"],  # (the sync's own schedule at the end)
        "truth": truth,
        "first_sample_ns": rows[0][0],
        "answering_again_ns": answering_again,
        "realtime_offset_ns": off,
    }


def _board_clock(seed: int, reset_s: float) -> tuple[DriftClock, list[str]]:
    """The board's clock for ``seed`` and the board process's arguments that make it."""
    rng = random.Random(seed)
    offset = rng.uniform(1e6, 1e9)
    skew = rng.choice((-1, 1)) * rng.uniform(50, 200)
    drift = rng.uniform(-0.5, 0.5)
    ref = time.monotonic_ns()
    extra = [
        *("--clock-offset-us", repr(offset), "--clock-skew-ppm", repr(skew)),
        *("--clock-drift-ppm-per-s", repr(drift), "--clock-ref-ns", str(ref)),
        *("--reset-at", repr(reset_s), "--boot-gap-ms", repr(GAP_MS), "--rate", "500"),
    ]
    return DriftClock(offset, skew, drift, ref, [reset_s]), extra


def _figures(rows: list[Row], answering_again: float) -> dict[str, Any]:
    """The run's errors against the truth: synced samples from 0.5 s after the first one."""
    first = rows[0][0]
    hosts = [r[1] for r in rows]
    not_increasing = sum(1 for a, b in itertools.pairwise(hosts) if b <= a)
    counted = [r for r in rows if r[0] >= first + 5e8 and not r[4] & 6]  # synced, not outliers
    signed = np.array([r[2] for r in counted]) / 1000
    err = np.abs(signed)
    bounds = np.array([r[3] for r in counted]) / 1000
    ests = np.array([r[5] for r in counted]) / 1000
    covered = float(np.mean(err <= bounds)) * 100
    # recovery: from the board answering again to the first synced sample within 50 µs, after
    # which none is worse
    after = [r for r in rows if r[0] >= answering_again]
    recovery = float("nan")
    for i, r in enumerate(after):
        if all(not x[4] & 6 and abs(x[2]) <= 50_000 for x in after[i:]):
            recovery = (r[0] - answering_again) / 1e6
            break
    return {
        "signed_us": signed,  # (for pooled figures over seeds)
        "err_us": err,
        "est_us": ests,
        "p50": float(np.percentile(err, 50)),
        "p99": float(np.percentile(err, 99)),
        "max": float(err.max()),
        "mean_signed": float(signed.mean()),
        "bound_p50": float(np.percentile(bounds, 50)),
        **est_stats(err, ests),
        "covered": covered,
        "not_increasing": not_increasing,
        "recovery_ms": recovery,
        "unsynced": sum(1 for r in rows if r[4] & 6),
        "n": len(rows),
    }
