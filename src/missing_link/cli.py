"""The ``missing-link`` command line.  Errors go to stderr with a non-zero exit code:
1 = the board or link failed, 2 = bad command line or input, 130 = interrupted."""

from __future__ import annotations

import argparse
import json
import math
import signal
import sys
import threading
import time
from collections.abc import Sequence
from typing import Any

from .errors import BadURL, ConfigError, DescriptorError, MissingLinkError
from .host.board import Board
from .host.samples import Sample, SampleDecoder
from .j2a import SifReceived
from .version import __version__

EXIT_FAIL = 1
EXIT_USAGE = 2
EXIT_INTERRUPTED = 130


def _parse_hex(text: str) -> bytes:
    cleaned = text.replace(" ", "").replace(":", "")
    try:
        return bytes.fromhex(cleaned)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--hex {text!r} is not hex bytes (e.g. 01ff or '01 ff')"
        ) from None


def _number(text: str, allow_zero: bool) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value) or value < 0 or (value == 0 and not allow_zero):
        raise argparse.ArgumentTypeError(f"{text} must be a number {'>=' if allow_zero else '>'} 0")
    return value


def _positive(text: str) -> float:
    return _number(text, allow_zero=False)


def _non_negative(text: str) -> float:
    return _number(text, allow_zero=True)


def _count(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"{value} must be 0 or more")
    return value


def _port(text: str) -> int:
    value = _count(text)
    if value > 65535:
        raise argparse.ArgumentTypeError(f"{value} is not a TCP port (0..65535)")
    return value


class _PublisherArg(argparse.Action):
    """``-p NAME`` (repeatable); its help lists the publishers this environment has, found only
    when the help is shown (finding them costs a look at the installed packages)."""

    def __init__(self, option_strings: list[str], dest: str, **kw: Any) -> None:
        super().__init__(option_strings, dest, metavar="NAME", **kw)

    @property
    def help(self) -> str:
        from .publishers.registry import available_publishers

        return f"add a publisher ({', '.join(available_publishers())} here)"

    @help.setter
    def help(self, value: str | None) -> None:
        pass  # (argparse sets it; the property above answers)

    def __call__(self, parser: Any, namespace: Any, values: Any, option: Any = None) -> None:
        setattr(namespace, self.dest, [*(getattr(namespace, self.dest, None) or []), values])


def _open(args: argparse.Namespace) -> Board:
    return Board.open(args.url, timeout=args.timeout)


def _emit_json(obj: Any) -> None:
    print(json.dumps(obj, sort_keys=False), flush=True)


# ---- info -------------------------------------------------------------------------------------
def info_dict(board: Board) -> dict[str, Any]:
    return {
        "url": board.url,
        "original": board.is_original,
        "functions": [{"index": i, "name": n} for i, n in enumerate(board.functions)],
        "properties": dict(board.properties),
        "transducers": None
        if board.transducers is None
        else [t.to_json() for t in board.transducers],
    }


def cmd_info(args: argparse.Namespace) -> int:
    with _open(args) as board:
        if args.json:
            _emit_json(info_dict(board))
            return 0
        kind = (
            "original (Part 1) board"
            if board.is_original
            else f"J2A {board.properties['j2a.version']} board"
        )
        print(f"{board.name} at {board.url}: {kind}")
        print("functions:")
        for i, name in enumerate(board.functions):
            print(f"  {i:3d}  {name}")
        print("properties:")
        width = max((len(k) for k in board.properties), default=0)
        for k, v in board.properties.items():
            print(f"  {k:<{width}}  {v}")
        print("transducers:")
        if board.transducers is None:
            print("  (none described: an original board; give descriptors on the host side)")
        for t in board.transducers or []:
            opts = " ".join(f"{k}={v}" for k, v in t.options.items())
            print(
                f"  {t.id:3d}  {t.name:<12} {t.model:<12} {t.chan_count:3d} x {t.dtype:<9} "
                f"N/A={t.na}  {opts}"
            )
            if t.unknown:
                print(f"       unknown keys (ignored): {', '.join(t.unknown)}")
    return 0


# ---- call -------------------------------------------------------------------------------------
#: return values that mean success for built-ins whose OK is not 0 (spec 1.6)
SUCCESS_CODES = {"a2jEcho": 0xBA}


def cmd_call(args: argparse.Namespace) -> int:
    if len(args.hex) > 255:
        print(
            f"missing-link: error: --hex has {len(args.hex)} bytes; one J2A frame carries at "
            "most 255 (larger transfers go through a many-function)",
            file=sys.stderr,
        )
        return EXIT_USAGE
    with _open(args) as board:
        result = board.call(args.name, args.hex, timeout=args.timeout)
    if args.json:
        _emit_json(
            {
                "function": args.name,
                "code": result.code,
                "ok": result.ok,
                "payload": result.payload.hex(),
            }
        )
    else:
        text = result.payload.decode("ascii", "replace") if result.payload.isascii() else ""
        print(f"return {result.code:#04x} ({result.code})  payload {len(result.payload)} bytes")
        if result.payload:
            print(f"  hex   {result.payload.hex(' ')}")
            if text.isprintable():
                print(f"  ascii {text}")
    if result.code != SUCCESS_CODES.get(args.name, 0) and not args.any_code:
        print(
            f"missing-link: error: {args.name} returned {result.code:#04x} (not OK; "
            "--any-code accepts every return value)",
            file=sys.stderr,
        )
        return EXIT_FAIL
    return 0


# ---- listen -----------------------------------------------------------------------------------
def format_sample(s: Sample, unit: str | None) -> str:
    value = "N/A" if s.value is None else f"{s.value}{(' ' + unit) if unit else ''}"
    lost = f"  (lost {s.lost} SIFs before)" if s.lost else ""
    where = f"{s.board}/{s.transducer}[{s.channel}]"
    return f"{s.host_rx:14.6f}  {where} = {value}  @board {s.board_us} us{lost}"


def cmd_listen(args: argparse.Namespace) -> int:
    done = threading.Event()
    count = 0
    lock = threading.Lock()
    with _open(args) as board:
        transducers = board.transducers or []
        decoder = SampleDecoder(board.name, transducers)
        units = {t.name: t.unit for t in transducers}
        wanted = set(args.transducer or [])
        unknown = wanted - set(units)
        if unknown:
            have = ", ".join(units) or "none (an original board without descriptors)"
            print(
                f"missing-link: error: {board.name} has no transducer "
                f"{', '.join(sorted(unknown))} (it has: {have})",
                file=sys.stderr,
            )
            return EXIT_USAGE

        def on_sif(sif: SifReceived, now: float) -> None:
            nonlocal count
            with lock:
                if done.is_set():
                    return
                if not transducers:
                    lines = [
                        f"{now:14.6f}  sif cmd={sif.cmd} seq={sif.seq} lost={sif.lost}"
                        f" {sif.payload.hex()}"
                    ]
                    objs: list[dict[str, object]] = [
                        {
                            "cmd": sif.cmd,
                            "seq": sif.seq,
                            "lost": sif.lost,
                            "payload": sif.payload.hex(),
                            "host_rx": now,
                        }
                    ]
                else:
                    samples = [
                        s
                        for s in decoder.decode(sif, now, keep_missing=args.missing)
                        if not wanted or s.transducer in wanted
                    ]
                    lines = [format_sample(s, units.get(s.transducer)) for s in samples]
                    objs = [s.to_json() for s in samples]
                for line, obj in zip(lines, objs, strict=True):
                    if args.count and count >= args.count:
                        done.set()
                        return
                    if args.json:
                        print(json.dumps(obj), flush=False)
                    else:
                        print(line, flush=False)
                    count += 1
                sys.stdout.flush()
                if args.count and count >= args.count:
                    done.set()

        board.on_sif(None, on_sif)
        deadline = time.monotonic() + args.duration if args.duration else None
        while not done.is_set() and board.alive:
            if deadline is not None and time.monotonic() >= deadline:
                break
            done.wait(0.1)
        done.set()
        if not board.alive:
            print(f"missing-link: error: {board.url}: link lost", file=sys.stderr)
            return EXIT_FAIL
    return 0


# ---- sync -------------------------------------------------------------------------------------
def cmd_sync(args: argparse.Namespace) -> int:
    from .errors import CallTimeout
    from .timesync import ClockSync, SyncOptions

    if args.period <= 0:
        print("missing-link: error: --period must be > 0", file=sys.stderr)
        return EXIT_USAGE
    if args.uart_baud and not args.url.removeprefix("spy+").startswith("serial://"):
        print(
            "missing-link: error: --uart-baud describes a UART link (serial://); "
            f"{args.url} is not one, and its bytes do not take UART time",
            file=sys.stderr,
        )
        return EXIT_USAGE
    byte_ns = 10e9 / args.uart_baud if args.uart_baud else 0.0
    with _open(args) as board:
        if "a2jClock" not in board.index and "getTime" not in board.index:
            print(
                f"missing-link: error: {board.name} has neither a2jClock nor getTime",
                file=sys.stderr,
            )
            return EXIT_FAIL
        res = board.properties.get("clock.res_us", "1")
        sync = ClockSync(SyncOptions(res_us=int(res) if res.isdigit() else 1))
        start = time.monotonic()
        sync.start(start)
        next_print = start + args.period
        end = start + args.duration if args.duration else None
        if not args.json:
            print(f"clock sync with {board.name} at {board.url} (Ctrl-C to stop)", flush=True)
        while board.alive:
            now = time.monotonic()
            if end is not None and now >= end:
                break
            wait = min(sync.due(), next_print) - now
            if wait > 0:
                time.sleep(wait)
                continue
            if now >= sync.due():
                try:
                    sync.on_exchange(board.clock_exchange(args.timeout, byte_ns=byte_ns), now)
                except CallTimeout:
                    sync.on_lost(time.monotonic())
            if now >= next_print:
                next_print += args.period
                st = sync.status()
                st["t_s"] = round(now - start, 3)
                if args.json:
                    _emit_json(st)
                else:
                    print(format_sync(st), flush=True)
        if not board.alive:
            print(f"missing-link: error: {board.url}: link lost", file=sys.stderr)
            return EXIT_FAIL
    return 0


def format_sync(st: dict[str, Any]) -> str:
    head = f"{st['t_s']:7.1f}s {st['sync_state']:<9}"
    if "offset_us" not in st:
        return f"{head} no estimate yet (exchanges {st['sync_exchanges']}, lost {st['sync_lost']})"
    return (
        f"{head} offset {st['offset_us']:+.3f} µs  skew {st['skew_ppm']:+8.3f} ppm"
        f"  bound ±{st['bound_us']:.1f} µs  sigma {st['sigma_us']:.1f} µs"
        f"  rtt {st['sync_rtt_us']:.0f} µs (min {st['sync_min_rtt_us']:.0f})"
        f"  every {st['sync_interval_ms']:.0f} ms  exchanges {st['sync_exchanges']}"
        f" lost {st['sync_lost']}"
    )


# ---- create-msgs ------------------------------------------------------------------------------
def cmd_create_msgs(args: argparse.Namespace) -> int:
    import os

    from .descriptors import load_descriptor_file
    from .ros.msgs import check_package, package_files
    from .ros.package import write_package

    try:
        check_package(args.package)
    except ValueError as e:
        print(f"missing-link: error: {e}", file=sys.stderr)
        return EXIT_USAGE
    if args.build and args.ros != 2:
        print("missing-link: error: --build builds ROS 2 packages (--ros 2)", file=sys.stderr)
        return EXIT_USAGE
    if os.path.exists(args.source):
        transducers = load_descriptor_file(args.source)
        origin = args.source
    else:
        with Board.open(args.source, timeout=args.timeout) as board:
            if board.transducers is None:
                print(
                    f"missing-link: error: {board.name} is an original board without descriptors;"
                    " give them in a file (see docs/descriptors.md)",
                    file=sys.stderr,
                )
                return EXIT_USAGE
            transducers = board.transducers
            origin = board.name
    files = package_files(transducers, args.package, args.ros)
    try:
        written = write_package(args.out, args.package, files, force=args.force)
    except (FileExistsError, NotADirectoryError) as e:
        print(f"missing-link: error: {e}", file=sys.stderr)
        return EXIT_USAGE
    except OSError as e:
        print(
            f"missing-link: error: cannot write into {args.out}: {e.strerror or e}", file=sys.stderr
        )
        return EXIT_FAIL
    for path in written:
        print(path)
    print(
        f"{len(transducers)} message type(s) from {origin} in ROS {args.ros} package "
        f"{args.package}"
        + (
            ""
            if args.build
            else f" ({'colcon build' if args.ros == 2 else 'catkin_make'} to build it)"
        ),
        file=sys.stderr,
    )
    if args.build:
        from .ros.build import build_package

        root = os.path.join(args.out, args.package)
        log = build_package(
            root, args.build, progress=lambda line: print(f"  {line}", file=sys.stderr, flush=True)
        )
        print(
            f"built and installed into {args.build} (log {log}); the daemon finds it with "
            f'[ros2] prefix = "{os.path.abspath(args.build)}" or '
            f"MISSING_LINK_ROS2_PREFIX={os.path.abspath(args.build)}",
            file=sys.stderr,
        )
    return 0


# ---- run ----------------------------------------------------------------------------------------
def build_config(args: argparse.Namespace) -> Any:
    from .daemon.config import BoardSpec, Config, DiscoverSpec, load_config
    from .publishers.registry import unavailable

    cfg = load_config(args.config) if args.config else Config(publishers=["bus", "console"])
    cfg.boards.extend(BoardSpec(url=u) for u in args.url)
    for name in args.publisher or []:
        why = unavailable(name)
        if why is not None:
            raise ConfigError(f"--publisher {name!r}: {why}")
        if name not in cfg.publishers:
            cfg.publishers.append(name)
    if args.foxglove is not None:
        if "foxglove" not in cfg.publishers:
            cfg.publishers.append("foxglove")
        cfg.publisher_options.setdefault("foxglove", {})["port"] = args.foxglove
    if args.record:
        if "mcap" not in cfg.publishers:
            cfg.publishers.append("mcap")
        cfg.publisher_options.setdefault("mcap", {})["path"] = args.record
    if getattr(args, "auto", False) and cfg.discover is None:
        cfg.discover = DiscoverSpec()
    if not cfg.boards and cfg.discover is None:
        raise BadURL(
            "no boards: give URLs on the command line, [[board]] tables or [discover] in "
            "--config, or --auto"
        )
    return cfg


def cmd_run(args: argparse.Namespace) -> int:
    from .daemon import Daemon

    daemon = Daemon(build_config(args))  # config, URL and descriptor errors: exit 2, at once
    stop = threading.Event()
    interrupted = []

    def on_signal(signum: int, frame: object) -> None:
        if signum == signal.SIGINT:
            interrupted.append(signum)
        stop.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    code = 0
    with daemon:
        if daemon.discovery is not None:
            globs = " ".join(daemon.discovery.spec.ports)
            print(f"missing-link: discovering boards on {globs}", file=sys.stderr)
        print(
            f"missing-link: running {len(daemon.sessions)} board(s), publishers: "
            f"{', '.join(p.name for p in daemon.publishers)} (Ctrl-C stops)",
            file=sys.stderr,
        )
        for p in daemon.publishers:
            url = getattr(p, "url", None)
            if url:
                print(f"missing-link: {p.name} at {url}", file=sys.stderr)
        if args.wait_up and not daemon.wait_until_up(args.wait_up):
            for s in daemon.sessions:
                if s.state != "up":
                    print(
                        f"missing-link: error: {s.spec.url}: not up within {args.wait_up:g} s: "
                        f"{s.error or s.state}",
                        file=sys.stderr,
                    )
            code = EXIT_FAIL
        elif args.view:
            from .view import LiveView

            LiveView(daemon).run(stop, args.duration or None)
        else:
            _wait_watching(daemon, stop, args.duration or None)
    print_summary(daemon, sys.stderr)
    failures = daemon.failures()
    for line in failures:
        print(f"missing-link: error: {line}", file=sys.stderr)
    if interrupted:
        return EXIT_INTERRUPTED
    return EXIT_FAIL if failures else code


def _wait_watching(daemon: Any, stop: threading.Event, duration: float | None) -> None:
    """Wait for the end; a publisher that fails for good (a recording that cannot write) ends
    the run at once, loudly, rather than running on without it."""
    deadline = None if duration is None else time.monotonic() + duration
    while not stop.wait(0.2):
        if daemon.failures():
            return
        if deadline is not None and time.monotonic() >= deadline:
            return


def print_summary(daemon: Any, out: Any) -> None:
    """What happened, with a number next to every loss: per board, then per publisher."""
    for s in daemon.status():
        extra = [
            f"{s[k]} {label}"
            for k, label in (
                ("lost_sifs", "lost SIFs"),
                ("bad_sifs", "bad SIFs"),
                ("unknown_sifs", "unknown SIFs"),
                ("clock_outliers", "clock outliers"),
                ("bad_checksums", "bad checksums"),
                ("stale_links", "stale links"),
            )
            if s.get(k)
        ]
        print(
            f"missing-link: {s['board']}: {s['samples']} samples"
            + "".join(f", {e}" for e in extra)
            + f", {s['connects']} connect(s), state {s['state']}"
            + (f" ({s['error']})" if s["error"] and s["state"] != "up" else ""),
            file=out,
        )
    for p in daemon.publishers:
        st = p.status()
        bits = []
        if "messages" in st:
            bits.append(f"{st['messages']} messages")
        bits.append(f"{st.get('dropped', 0)} dropped")
        bags = getattr(p, "bags", None)
        if bags:
            bits.append("recorded " + ", ".join(str(b) for b in bags))
        if p.name != "bus" or st.get("dropped"):
            print(f"missing-link: publisher {p.name}: {', '.join(bits)}", file=out)


def cmd_recover(args: argparse.Namespace) -> int:
    from .publishers.recover import recover_bag

    try:
        dest, count = recover_bag(args.path, args.out)
    except (FileNotFoundError, FileExistsError, ValueError) as e:
        print(f"missing-link: error: {e}", file=sys.stderr)
        return EXIT_USAGE
    except OSError as e:
        print(f"missing-link: error: cannot recover {args.path}: {e}", file=sys.stderr)
        return EXIT_FAIL
    print(f"recovered {count} messages into {dest}")
    return 0


# ---- flash ------------------------------------------------------------------------------------
def cmd_flash(args: argparse.Namespace) -> int:
    from .boardfile import load_board_file
    from .flash import flash

    bf = load_board_file(args.boardfile)
    return flash(bf, args.port, dry_run=args.dry_run, check=not args.no_check)


def cmd_gen_firmware(args: argparse.Namespace) -> int:
    from pathlib import Path

    from .avrgen import write_avr
    from .boardfile import load_board_file

    bf = load_board_file(args.boardfile)
    for path in write_avr(bf, Path(args.out)):
        print(f"wrote {path}")
    return 0


# ---- board ------------------------------------------------------------------------------------
def cmd_board(args: argparse.Namespace) -> int:
    from .virtual import BoardServer, make_sim

    try:
        extra: dict[str, Any] = {"name": args.name} if args.name else {}
        if args.rate or args.channels:
            if args.sim != "rate":
                raise ValueError("--rate and --channels go with --sim rate")
            extra["rate_hz"] = args.rate or 100.0
            extra["channels"] = args.channels or 1
        drifting = args.clock_drift_ppm_per_s or args.reset_at or args.clock_ref_ns is not None
        if drifting:
            from .virtual.sims import DriftClock

            extra["clock"] = DriftClock(
                args.clock_offset_us or 0.0,
                args.clock_skew_ppm or 0.0,
                args.clock_drift_ppm_per_s or 0.0,
                args.clock_ref_ns,
                args.reset_at,
            )
        elif args.clock_offset_us is not None or args.clock_skew_ppm is not None:
            from .virtual.sims import AffineClock

            extra["clock"] = AffineClock(args.clock_offset_us or 0.0, args.clock_skew_ppm or 0.0)
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
    from .virtual import BoardServer, make_sim

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


# ---- relay ------------------------------------------------------------------------------------
def cmd_relay(args: argparse.Namespace) -> int:
    """A fault-injecting relay in front of a board (see missing_link.faults)."""
    from .faults import FaultRelay, Faults

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


# ---- router -----------------------------------------------------------------------------------
def cmd_router(args: argparse.Namespace) -> int:
    """A Zenoh router (like rmw_zenohd, without ROS 2): daemons and consumers on several
    machines meet here.  Multicast scouting off; prints one READY line, stops on SIGINT/SIGTERM."""
    import zenoh

    for endpoint in (args.listen or []) + (args.connect or []):
        if "/" not in endpoint or "://" in endpoint:
            print(
                f"missing-link: error: {endpoint!r} is not a Zenoh endpoint "
                "(e.g. tcp/127.0.0.1:7447)",
                file=sys.stderr,
            )
            return EXIT_USAGE
    if not args.listen:
        print("missing-link: error: --listen ENDPOINT is required", file=sys.stderr)
        return EXIT_USAGE
    cfg = zenoh.Config()
    cfg.insert_json5("mode", '"router"')
    cfg.insert_json5("listen/endpoints", json.dumps(args.listen))
    cfg.insert_json5("connect/endpoints", json.dumps(args.connect or []))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *a: stop.set())
    signal.signal(signal.SIGINT, lambda *a: stop.set())
    try:
        session = zenoh.open(cfg)
    except zenoh.ZError as e:
        print(
            f"missing-link: error: zenoh router on {', '.join(args.listen)}: {e}", file=sys.stderr
        )
        return EXIT_FAIL
    with session:
        print(f"READY zenoh router {session.info.zid()} on {', '.join(args.listen)}", flush=True)
        stop.wait()
    return 0


# ---- demo -------------------------------------------------------------------------------------
def cmd_demo(args: argparse.Namespace) -> int:
    from .demo import run_demo

    if args.duration < 1:
        print("missing-link: error: --duration must be at least 1 s", file=sys.stderr)
        return EXIT_USAGE
    return run_demo(duration=args.duration, seed=args.seed, record=args.record)


# ---- parser -----------------------------------------------------------------------------------
def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="missing-link",
        description="Sensor boards on a J2A link: inspect, call, listen, simulate.",
        epilog="Board URLs: tcp://HOST:PORT, unix:///PATH, serial:///dev/ttyACM0?baud=115200, "
        "usb://[BUS:ADDR][?serial=S], memory://NAME; prefix spy+ to hex-dump the traffic.",
    )
    p.add_argument("--version", action="version", version=f"missing-link {__version__}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def with_url(sp: argparse.ArgumentParser) -> None:
        sp.add_argument("url", help="board URL, e.g. serial:///dev/ttyACM0 or tcp://127.0.0.1:5000")
        sp.add_argument(
            "--timeout", type=_positive, default=1.0, help="per-call timeout in seconds (1.0)"
        )

    sp = sub.add_parser("info", help="functions, properties and transducers of a board")
    with_url(sp)
    sp.add_argument("--json", action="store_true", help="machine-readable output (docs/cli.md)")
    sp.set_defaults(func=cmd_info)

    sp = sub.add_parser("call", help="call a board function by name")
    with_url(sp)
    sp.add_argument("name", help="function name, e.g. a2jEcho")
    sp.add_argument("--hex", type=_parse_hex, default=b"", help="request payload as hex")
    sp.add_argument("--json", action="store_true")
    sp.add_argument(
        "--any-code",
        action="store_true",
        help="exit 0 whatever the function returns (default: 1 unless it returns OK)",
    )
    sp.set_defaults(func=cmd_call)

    sp = sub.add_parser("listen", help="print decoded samples live, one line each")
    with_url(sp)
    sp.add_argument("--count", type=_count, default=0, help="stop after N samples")
    sp.add_argument("--duration", type=_non_negative, default=0, help="stop after S seconds")
    sp.add_argument("--transducer", "-t", action="append", help="only this transducer (repeatable)")
    sp.add_argument("--missing", action="store_true", help="also print N/A channels")
    sp.add_argument("--json", action="store_true", help="one JSON object per line")
    sp.set_defaults(func=cmd_listen)

    sp = sub.add_parser("sync", help="clock synchronisation with a board, live")
    with_url(sp)
    sp.add_argument("--duration", type=_non_negative, default=0, help="stop after S seconds")
    sp.add_argument("--period", type=_positive, default=1.0, help="seconds between lines (1.0)")
    sp.add_argument("--uart-baud", type=_count, default=0, help="baud rate if the link is a UART")
    sp.add_argument("--json", action="store_true", help="one JSON object per line")
    sp.set_defaults(func=cmd_sync)

    sp = sub.add_parser("create-msgs", help="write .msg files and a ROS package from descriptors")
    sp.add_argument("source", help="board URL, or a descriptor file (.toml or transds/1 text)")
    sp.add_argument("--out", required=True, help="directory to write the package into")
    sp.add_argument("--ros", type=int, choices=(1, 2), default=2, help="ROS version (2)")
    sp.add_argument("--package", default="missing_link_msgs", help="package name")
    sp.add_argument("--timeout", type=_positive, default=1.0)
    sp.add_argument(
        "--force", action="store_true", help="replace a package directory create-msgs did not write"
    )
    sp.add_argument(
        "--build",
        metavar="PREFIX",
        help="build the ROS 2 package with the ROS 2 in this environment and install it there",
    )
    sp.set_defaults(func=cmd_create_msgs)

    sp = sub.add_parser("run", help="the daemon: every board's transducers as topics")
    sp.add_argument("url", nargs="*", help="board URLs (added to those in --config)")
    sp.add_argument("--config", help="TOML configuration (see examples/missing-link.toml)")
    sp.add_argument("--publisher", "-p", action=_PublisherArg)
    sp.add_argument("--record", metavar="DIR", help="record everything to rosbag2/MCAP under DIR")
    sp.add_argument(
        "--foxglove",
        nargs="?",
        type=_port,
        const=8765,
        metavar="PORT",
        help="live view for Foxglove on ws://127.0.0.1:PORT (8765)",
    )
    sp.add_argument(
        "--duration", type=_non_negative, default=0, help="stop after S seconds (0 = run)"
    )
    sp.add_argument(
        "--wait-up",
        type=_non_negative,
        default=0,
        metavar="S",
        help="fail (exit 1) unless every board is up within S seconds",
    )
    sp.add_argument("--view", action="store_true", help="a live view of boards and topics")
    sp.add_argument(
        "--auto",
        action="store_true",
        help="find J2A boards on USB serial ports as they appear ([discover] in --config)",
    )
    sp.set_defaults(func=cmd_run)

    sp = sub.add_parser("flash", help="put the firmware for a board file on a board")
    sp.add_argument("boardfile", help="board file (BOARD = {...}, see examples/boards/)")
    sp.add_argument("--port", default="/dev/ttyACM0", help="serial port (/dev/ttyACM0)")
    sp.add_argument("--dry-run", action="store_true", help="list files and commands, touch nothing")
    sp.add_argument(
        "--no-check", action="store_true", help="do not check the board answers J2A afterwards"
    )
    sp.set_defaults(func=cmd_flash)

    sp = sub.add_parser("gen-firmware", help="C tables for an AVR board from its board file")
    sp.add_argument("boardfile", help="board file with mcu = atmega328p, atmega2560 or atmega32u4")
    sp.add_argument("--target", choices=["avr"], default="avr", help="firmware target (avr)")
    sp.add_argument("--out", required=True, help="directory for board_gen.c and board.mk")
    sp.set_defaults(func=cmd_gen_firmware)

    sp = sub.add_parser("recover", help="salvage a recording whose process died")
    sp.add_argument("path", help="bag directory or .mcap file")
    sp.add_argument("--out", help="new bag directory (default: PATH_recovered)")
    sp.set_defaults(func=cmd_recover)

    sp = sub.add_parser("board", help="run a virtual board")
    sp.add_argument("--sim", required=True, help="thesis, encoder_servo, rangers, original or rate")
    sp.add_argument(
        "--listen", required=True, help="tcp://127.0.0.1:PORT (0 = any), unix:///PATH or pty"
    )
    sp.add_argument("--seed", type=int, default=0, help="random seed of the simulated signals")
    sp.add_argument("--name", help="board.name property (default: the sim's)")
    sp.add_argument(
        "--count",
        type=int,
        default=1,
        help="serve N boards from this process (NAME_0 .. NAME_N-1, tcp only; benchmarks)",
    )
    sp.add_argument("--rate", type=float, help="updates per second (sim rate only)")
    sp.add_argument("--channels", type=int, help="channels per update (sim rate only)")
    sp.add_argument(
        "--clock-offset-us",
        type=float,
        help="board clock = OFFSET + (1 + SKEW) * host CLOCK_MONOTONIC (default: the host's clock)",
    )
    sp.add_argument("--clock-skew-ppm", type=float, help="the board clock's rate error (ppm)")
    sp.add_argument(
        "--clock-drift-ppm-per-s", type=float, help="the rate error changes this much per second"
    )
    sp.add_argument(
        "--clock-ref-ns",
        type=int,
        help="host CLOCK_MONOTONIC ns the drift and --reset-at count from (default: now)",
    )
    sp.add_argument(
        "--reset-at",
        type=float,
        action="append",
        metavar="S",
        help="the board resets S seconds after --clock-ref-ns (repeatable); the link stays",
    )
    sp.add_argument("--boot-gap-ms", type=float, default=100.0, help="silence after a reset (100)")
    sp.set_defaults(func=cmd_board)

    sp = sub.add_parser("relay", help="a fault-injecting relay in front of a board (tests)")
    sp.add_argument("url", help="the board's URL (tcp, unix, serial, ...)")
    sp.add_argument(
        "--listen", default="tcp://127.0.0.1:0", help="tcp://127.0.0.1:PORT or unix:///PATH"
    )
    sp.add_argument("--corrupt", type=float, default=0.0, help="per-byte bit-flip probability")
    sp.add_argument("--drop", type=float, default=0.0, help="per-chunk loss probability")
    sp.add_argument("--delay-ms", type=float, default=0.0, help="hold every chunk this long")
    sp.add_argument(
        "--blackhole-after", type=float, help="forward nothing after S s of a connection"
    )
    sp.add_argument("--blackhole-for", type=float, help="... for S s (default: for ever)")
    sp.add_argument("--seed", type=int, default=0)
    sp.add_argument(
        "--duration", type=_non_negative, default=0, help="stop after S seconds (0 = run)"
    )
    sp.set_defaults(func=cmd_relay)

    sp = sub.add_parser("router", help="a Zenoh router for daemons and consumers on several hosts")
    sp.add_argument(
        "--listen", action="append", help="endpoint, e.g. tcp/0.0.0.0:7447 (repeatable)"
    )
    sp.add_argument("--connect", action="append", help="another router to join (repeatable)")
    sp.set_defaults(func=cmd_router)

    sp = sub.add_parser("demo", help="the thesis test rig on two virtual boards, recorded")
    sp.add_argument("--duration", type=float, default=20.0, help="seconds to run (20)")
    sp.add_argument("--record", default="recordings", help="recording directory (recordings)")
    sp.add_argument("--seed", type=int, default=0)
    sp.set_defaults(func=cmd_demo)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except (BadURL, DescriptorError, ConfigError) as e:
        print(f"missing-link: error: {e}", file=sys.stderr)
        return EXIT_USAGE
    except MissingLinkError as e:
        print(f"missing-link: error: {e}", file=sys.stderr)
        return EXIT_FAIL
    except KeyboardInterrupt:
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        return 0


if __name__ == "__main__":
    sys.exit(main())
