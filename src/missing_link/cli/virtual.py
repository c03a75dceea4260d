"""``board`` (a virtual board) and ``relay`` (a fault-injecting relay): boards to test with."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from typing import Any

from .common import EXIT_FAIL, EXIT_USAGE


def _sim_options(args: argparse.Namespace) -> dict[str, Any]:
    """``make_sim``'s keyword arguments from the command line (ValueError: a usage error)."""
    extra: dict[str, Any] = {"name": args.name} if args.name else {}
    if args.config_file:
        if args.sim not in ("thesis", "encoder_servo", "rangers", "rate", "aligned"):
            raise ValueError(f"--config-file: the {args.sim} board has no configuration")
        extra["config_file"] = args.config_file
    if args.rate or args.channels:
        if args.sim not in ("rate", "aligned") or (args.channels and args.sim != "rate"):
            raise ValueError("--rate goes with --sim rate or aligned, --channels with rate")
        extra["rate_hz"] = args.rate or (100.0 if args.sim == "rate" else 50.0)
        if args.sim == "rate":
            extra["channels"] = args.channels or 1
    drifting = args.clock_drift_ppm_per_s or args.reset_at or args.clock_ref_ns is not None
    if drifting:
        from ..virtual.clocks import DriftClock

        extra["clock"] = DriftClock(
            args.clock_offset_us or 0.0,
            args.clock_skew_ppm or 0.0,
            args.clock_drift_ppm_per_s or 0.0,
            args.clock_ref_ns,
            args.reset_at,
        )
    elif args.clock_offset_us is not None or args.clock_skew_ppm is not None:
        from ..virtual.clocks import AffineClock

        extra["clock"] = AffineClock(args.clock_offset_us or 0.0, args.clock_skew_ppm or 0.0)
    return extra


def cmd_board(args: argparse.Namespace) -> int:
    from ..virtual import BoardServer, make_sim

    try:
        extra = _sim_options(args)
        runtime = make_sim(args.sim, seed=args.seed, **extra)
    except ValueError as e:
        print(f"missing-link: error: {e}", file=sys.stderr)
        return EXIT_USAGE
    resets = []
    if args.reset_at:
        clock = extra["clock"]
        resets = [(r, round(args.boot_gap_ms * 1e6)) for r in clock.reset_ns]
    if args.count > 1:
        return _serve_many(args, extra)
    try:
        server = BoardServer(
            runtime,
            args.listen,
            resets=resets,
            rebuild=lambda: make_sim(args.sim, seed=args.seed, **extra),
        )
    except OSError as e:
        print(
            f"missing-link: error: cannot listen on {args.listen}: {e.strerror or e}",
            file=sys.stderr,
        )
        return EXIT_FAIL

    def stop(signum: int, frame: object) -> None:
        server.stop()

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    print(f"LISTENING {server.url}", flush=True)
    server.serve_forever()
    return 0


def _serve_many(args: argparse.Namespace, extra: dict[str, Any]) -> int:
    """``board --count N``: N boards in this one process (a thread each), named NAME_0.. and
    seeded SEED.., one LISTENING line each: benchmarks load the host, not N board processes."""
    from ..virtual import BoardServer, make_sim

    if not args.listen.startswith("tcp://") or not args.listen.endswith(":0"):
        print("missing-link: error: --count needs --listen tcp://HOST:0", file=sys.stderr)
        return EXIT_USAGE
    base = extra.pop("name", None) or args.sim
    servers = []
    for k in range(args.count):
        runtime = make_sim(args.sim, seed=args.seed + k, name=f"{base}_{k}", **extra)
        servers.append(BoardServer(runtime, args.listen))
    threads = [
        threading.Thread(target=s.serve_forever, name=f"board:{s.url}", daemon=True)
        for s in servers
    ]
    for t in threads:
        t.start()
    done = threading.Event()

    def stop(signum: int, frame: object) -> None:
        done.set()

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    for s in servers:
        print(f"LISTENING {s.url}", flush=True)
    done.wait()
    for s in servers:
        s.stop()
    for t in threads:
        t.join(2)
    return 0


def cmd_relay(args: argparse.Namespace) -> int:
    """A fault-injecting relay in front of a board (see missing_link.virtual.faults)."""
    from ..virtual.faults import FaultRelay, Faults

    try:
        faults = Faults(
            corrupt=args.corrupt,
            drop=args.drop,
            delay_s=args.delay_ms / 1000.0,
            blackhole_after=args.blackhole_after,
            blackhole_for=args.blackhole_for,
            seed=args.seed,
        ).check()
    except ValueError as e:
        print(f"missing-link: error: {e}", file=sys.stderr)
        return EXIT_USAGE
    relay = FaultRelay(args.url, faults, args.listen)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *a: stop.set())
    signal.signal(signal.SIGINT, lambda *a: stop.set())
    relay.start()
    print(f"LISTENING {relay.url}", flush=True)
    stop.wait(args.duration or None)
    relay.stop()
    counts = ", ".join(f"{k} {v}" for k, v in relay.counters().items())
    print(f"relay: {counts}", file=sys.stderr)
    for line in relay.errors[-5:]:
        print(f"relay: {line}", file=sys.stderr)
    return 0
