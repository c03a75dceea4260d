"""Record real clock exchanges once, replay them through the clock sync offline: a paired
comparison of probe schedules (and, across two checkouts, of estimator code) on the very same
link behaviour, which repeated real runs on a noisy machine cannot give (the same code's
whole-run p50 moves by 4 µs or more between runs here).

    .venv/bin/python bench/replay_timesync.py record [--runs 6] [--seconds 30] [--out DIR]
    .venv/bin/python bench/replay_timesync.py replay [--in DIR] [--set key=value,...]...
    .venv/bin/python bench/replay_timesync.py floors [--in DIR]

``record`` runs the whole-run scenario of ``bench_timesync.py`` (a board process whose clock has
a random offset, ±50-200 ppm skew, a drifting skew and a reset 18 s in, over a pty) with the
daemon probing at a fixed 50 Hz, and writes every exchange (as the daemon hands them to
recordings) with the board clock's parameters (one JSON file per run); a run whose sync did not
keep the 50 Hz schedule stops it (the schedule is patched into the daemon: bench/_patch.py; the
rate against wall time is printed: a busy machine makes it lower, not the schedule).

``replay`` feeds each recording to a fresh ``ClockSync``: whenever the sync asks for a probe, it
gets the first recorded exchange sent at or after that moment (so any schedule slower than 50 Hz
can be replayed), and every 2 ms from 0.5 s after the first sample it maps the board's true
reading and compares with the truth, as the whole-run bench does. Each ``--set`` is one variant
of ``SyncOptions`` (``default`` = none); ``--anchors`` adds the anchors' methods of
``virtual/syncsim.py`` (Cristian/micro-ROS, rosserial, PX4) on the same exchanges at their own
probe rates. Medians over the recordings; error bins by time since the first sample; "before the
reset" counts only up to the board's reset (the anchor models, like the originals they stand
for, have no reset detection beyond re-syncing). ``floors`` gives each recording's one-way
delays against the known clock (their 1st percentiles, and the bias half their difference gives
an estimate that assumes the two trips alike)."""

from __future__ import annotations

import argparse
import bisect
import json
import math
import sys
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from _calibration import est_stats
from missing_link.publishers.base import Publisher
from missing_link.ros.clock import ClockRecord
from missing_link.timesync import Exchange, SyncOptions
from missing_link.topics import Update
from missing_link.virtual import syncsim as sim
from missing_link.virtual.clocks import DriftClock

BINS = ((0.5, 3.0), (3.0, 8.0), (8.0, 18.0), (18.0, 1e9))


#: the recorder's probe rate
RATE_HZ = 50.0


class ClockRecorder(Publisher):
    """Every clock exchange the daemon makes, as it hands them to recordings (``clock_record``:
    one record per exchange the sync took, refused or not)."""

    name = "clock-recorder"

    def __init__(self) -> None:
        self.records: list[ClockRecord] = []

    def publish(self, update: Update) -> None:
        pass

    def clock_record(self, topic: str, record: ClockRecord) -> None:
        self.records.append(record)

    def exchanges(self, realtime_offset_ns: int) -> list[Exchange]:
        """The exchanges, their host stamps back on CLOCK_MONOTONIC (records carry REALTIME)."""
        off = realtime_offset_ns
        return [
            Exchange(r.t1_ns - off, r.t2_us, r.t3_us, r.t4_ns - off, r.down_min_ns, r.up_min_ns)
            for r in self.records
        ]


def record(runs: int, seconds: float, out: Path, link: str = "pty") -> None:
    import missing_link.daemon.session.clock as session_clock
    from _patch import patched
    from _whole_run import whole_run

    # The sessions build their SyncOptions in daemon/session/clock.py, with no parameter for the
    # probe schedule: the recorder gives them a fixed 50 Hz (a burst that never ends), so that any
    # slower schedule can be replayed from the recording; after a lost probe (a busy machine)
    # or a surprise too, so fast_interval is the same gap.  The patch fails the bench if that
    # name is gone or unused, and a run whose sync did not keep that schedule is not kept (its
    # own interval, not the rate against wall time: a busy machine answers late, not less).
    def fixed_50hz(**kw: Any) -> SyncOptions:
        gap = 1 / RATE_HZ
        return SyncOptions(
            **kw, burst_interval=gap, interval=gap, fast_interval=gap, burst_count=10**9
        )

    out.mkdir(parents=True, exist_ok=True)
    with patched(session_clock, "SyncOptions", fixed_50hz):
        for k in range(runs):
            recorder = ClockRecorder()
            got = whole_run(link, seconds, 100 + k, extra_publishers=[recorder])
            seen = recorder.exchanges(got["realtime_offset_ns"])
            rate = len(seen) / ((seen[-1].t4 - seen[0].t1) / 1e9) if len(seen) > 1 else 0.0
            if got["interval_ms"] != 1000 / RATE_HZ:
                raise SystemExit(
                    f"replay_timesync: run {k + 1}: the sync probed every {got['interval_ms']} ms,"
                    f" not the {RATE_HZ:g} Hz asked: the recorder's schedule was not applied "
                    f"(not saved)"
                )
            _save(out / f"run{100 + k}.json", got, seen)
            print(
                f"run {k + 1}/{runs}: {len(seen)} exchanges ({rate:.1f}/s, {got['lost']} lost; "
                f"live p50 {got['p50']:.1f} µs)"
            )


def _save(path: Path, run: dict[str, Any], seen: list[Exchange]) -> None:
    """One recording: the exchanges, the board clock's parameters and the run's moments."""
    truth = run["truth"]
    doc = {
        "truth": {
            "offset_us": truth.offset_us,
            "skew_ppm": truth.skew * 1e6,
            "drift_ppm_per_s": truth.drift * 1e12,
            "ref_ns": truth.ref_ns,
            "resets_ns": truth.reset_ns,
        },
        "interval_ms": run["interval_ms"],  # the sync's schedule (RATE_HZ's gap)
        "first_sample_ns": run["first_sample_ns"],
        "answering_again_ns": run["answering_again_ns"],
        "exchanges": [[e.t1, e.t2, e.t3, e.t4, e.down_min_ns, e.up_min_ns] for e in seen],
    }
    path.write_text(json.dumps(doc))


def _truth(doc: dict[str, Any]) -> DriftClock:
    tr = doc["truth"]
    truth = DriftClock(tr["offset_us"], tr["skew_ppm"], tr["drift_ppm_per_s"], tr["ref_ns"], [])
    truth.reset_ns = list(tr["resets_ns"])
    return truth


def floors(where: Path) -> None:
    """Each recording's one-way delays against the board's known clock: the request's (t1 to
    the board's t2) and the reply's (t3 to t4); the floor is the 1st percentile, and half the
    difference of the floors is the bias it gives an estimate that assumes them equal."""
    docs = _docs(where)
    print("| recording | exchanges | request floor µs | reply floor µs | bias µs |")
    print("|---|---|---|---|---|")
    for name, doc in docs:
        truth = _truth(doc)
        up, down = [], []
        for row in doc["exchanges"]:
            ex = Exchange(*row)
            boot = truth.boot_at(ex.t1)
            if boot != truth.boot_at(ex.t4) or (boot and ex.t1 < doc["answering_again_ns"]):
                continue  # (across the reset, or the board not answering yet)
            up.append((truth.host_ns(ex.t2, boot) - ex.t1) / 1000)
            down.append((ex.t4 - truth.host_ns(ex.t3, boot)) / 1000)
        f_up, f_down = float(np.percentile(up, 1)), float(np.percentile(down, 1))
        bias = (f_down - f_up) / 2
        print(f"| {name} | {len(up)} | {f_up:.1f} | {f_down:.1f} | {bias:+.1f} |")


def _map_at(method: Any, board_us: int, now: float) -> tuple[float, float, float] | None:
    """(host ns, bound ns, estimated error ns) as published: ours as the daemon's sample path
    maps (with ``now``, refusing stamps from the future); an anchor by its own map, without a
    bound or an estimate."""
    if isinstance(method, sim.Ours):
        got = method.sync.map_many((board_us,), now)
        return None if got is None or got[2] < 0 else (got[0][0], float(got[2]), float(got[1]))
    mapped = method.map(board_us)
    return None if mapped is None else (mapped[0], math.inf, math.inf)


def replay_one(doc: dict[str, Any], method: Any) -> dict[str, Any]:
    """``method``: one of ``sim.METHODS`` (ours: ``sim.Ours``); it asks for its first probe at 0 s,
    which is the recording's first exchange."""
    truth = _truth(doc)
    exs = [Exchange(*row) for row in doc["exchanges"]]
    sent = [e.t1 for e in exs]
    first, again = doc["first_sample_ns"], doc["answering_again_ns"]
    rows: list[tuple[float, float, float, float]] = []  # (s since first, error µs, bound, est µs)
    h, i, used = first, 0, 0
    while True:
        k = bisect.bisect_left(sent, method.due() * 1e9, lo=i)
        if k >= len(exs):
            break
        ex = exs[k]
        while h < ex.t4:  # the samples measured before this reply came back
            if h >= first + 5e8 and not truth.reset_ns[0] <= h < again:
                got = _map_at(method, math.floor(truth.board_us_at(h)), h / 1e9)
                if got is not None:
                    rows.append(
                        ((h - first) / 1e9, (got[0] - h) / 1000, got[1] / 1000, got[2] / 1000)
                    )
            h += 2_000_000
        method.on_exchange(ex, ex.t4 / 1e9)
        used, i = used + 1, k + 1
    a = np.array(rows)
    t, signed, bound, est = a[:, 0], a[:, 1], a[:, 2], a[:, 3]
    err = np.abs(signed)
    before = t < (truth.reset_ns[0] - first) / 1e9
    bins = {}
    for lo, hi in BINS:
        m = (t >= lo) & (t < hi)
        bins[lo] = float(np.median(err[m])) if m.any() else math.nan
    return {
        "p50": float(np.percentile(err, 50)),
        "p99": float(np.percentile(err, 99)),
        "max": float(err.max()),
        "mean_signed": float(signed.mean()),
        **est_stats(err, est),
        "p99_before": float(np.percentile(err[before], 99)),
        "max_before": float(err[before].max()),
        "covered": float(np.mean(err <= bound)) * 100,
        "bound": float(np.median(bound)),
        "probes": used / ((exs[-1].t4 - exs[0].t1) / 1e9),
        "bins": bins,
    }


def variant(spec: str) -> SyncOptions:
    if spec == "default":
        return SyncOptions()
    base = SyncOptions()
    kw: dict[str, Any] = {}
    for item in spec.split(","):
        key, _, value = item.partition("=")
        if not hasattr(base, key):
            raise SystemExit(f"replay_timesync: no SyncOptions field {key!r}")
        kw[key] = type(getattr(base, key))(float(value))
    return SyncOptions(**kw)


def _load(path: Path) -> dict[str, Any]:
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise SystemExit(f"replay_timesync: {path}: not a recording ({e})") from None
    keys = ("truth", "exchanges", "first_sample_ns", "answering_again_ns")
    if not isinstance(doc, dict) or any(k not in doc for k in keys):
        raise SystemExit(f"replay_timesync: {path}: not a recording (needs {', '.join(keys)})")
    return doc


def _us(x: float) -> str:
    """µs, or whole seconds for the errors of a map still on the board's previous boot."""
    return f"{x / 1e6:,.0f} s" if x >= 1e6 else f"{x:.1f}"


def _docs(where: Path) -> list[tuple[str, dict[str, Any]]]:
    docs = [(p.stem, _load(p)) for p in sorted(where.glob("run*.json"))]
    if not docs:
        raise SystemExit(f"replay_timesync: no recordings in {where} (run `record` first)")
    return docs


def replay(where: Path, specs: list[str], anchors: bool) -> None:
    options = {s: variant(s) for s in specs}  # (a bad --set fails before any output)
    docs = [doc for _name, doc in _docs(where)]
    print(f"{len(docs)} recordings from {where}; medians over them, worst = the worst run\n")
    bins = " | ".join(f"p50 {lo:g}-{hi:g} s" if hi < 1e9 else f"p50 {lo:g} s-" for lo, hi in BINS)
    print(
        "| method | p50 µs | p99 µs | max µs (worst) | mean signed µs | before the reset: p99 /"
        " max µs | in bound | bound p50 µs | est / error | within 2 est | probes/s"
        f" | {bins} |"
    )
    print("|---" * (11 + len(BINS)) + "|")
    runs: list[tuple[str, Callable[[], Any]]] = [
        (f"missing-link ({s})", partial(sim.Ours, o)) for s, o in options.items()
    ]
    if anchors:
        runs += [(n, sim.METHODS[n]) for n in ("cristian", "px4", "rosserial")]
    for label, make in runs:
        rs = [replay_one(d, make()) for d in docs]

        def med(key: str, rs: list[dict[str, Any]] = rs) -> float:
            return float(np.median([r[key] for r in rs]))

        per_bin = " | ".join(_us(float(np.median([r["bins"][lo] for r in rs]))) for lo, _ in BINS)
        bounded = not math.isinf(med("bound"))
        covered = f"{min(r['covered'] for r in rs):.2f} %" if bounded else "-"
        bound = f"{med('bound'):.1f}" if bounded else "-"
        ratio = f"{med('est_ratio'):.2f}" if bounded else "-"
        within = f"{med('in_2est'):.1f} %" if bounded else "-"
        worst = max(r["max"] for r in rs)
        mean = med("mean_signed")
        signed = f"{mean:+.1f}" if abs(mean) < 1e6 else f"{mean / 1e6:+,.0f} s"
        print(
            f"| {label} | {_us(med('p50'))} | {_us(med('p99'))} | {_us(med('max'))}"
            f" ({_us(worst)}) | {signed} | {_us(med('p99_before'))} / {_us(med('max_before'))}"
            f" | {covered} | {bound} | {ratio} | {within} | {med('probes'):.1f} | {per_bin} |"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    rec = sub.add_parser("record")
    rec.add_argument("--runs", type=int, default=6)
    rec.add_argument("--seconds", type=float, default=30.0)
    rec.add_argument("--out", type=Path, default=Path("recordings/timesync"))
    rec.add_argument("--link", choices=("pty", "tcp"), default="pty")
    rep = sub.add_parser("replay")
    rep.add_argument("--in", dest="where", type=Path, default=Path("recordings/timesync"))
    rep.add_argument("--set", dest="specs", action="append", default=None)
    rep.add_argument("--anchors", action="store_true", help="the anchors' methods too")
    flo = sub.add_parser("floors", help="each recording's one-way delay floors and their bias")
    flo.add_argument("--in", dest="where", type=Path, default=Path("recordings/timesync"))
    a = ap.parse_args()
    if a.cmd == "record":
        sys.path.insert(0, str(Path(__file__).parent))
        record(a.runs, a.seconds, a.out, a.link)
    elif a.cmd == "floors":
        floors(a.where)
    else:
        replay(a.where, a.specs or ["default"], a.anchors)


if __name__ == "__main__":
    main()
