"""``board`` (a virtual board: a sim, or any board file) and ``relay`` (a fault-injecting relay):
boards to test with."""

from __future__ import annotations

import argparse
import signal
import sys
import tempfile
import threading
from pathlib import Path
from typing import Any

from ..errors import ConfigError
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

    if args.file is not None:
        return _board_file(args)
    if args.seed is None:
        args.seed = 0
    try:
        if args.runtime or args.absent or args.flash or args.world or args.world_control:
            raise ValueError(
                "--runtime, --absent, --flash, --world and --world-control go with --file BOARDFILE"
            )
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
            args.dial or args.listen,
            resets=resets,
            rebuild=lambda: make_sim(args.sim, seed=args.seed, **extra),
            dial=bool(args.dial),
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
    print(_ready(server.url), flush=True)
    server.serve_forever()
    return 0


def _ready(url: str) -> str:
    """The line a board prints once it serves: LISTENING URL, or DIALING URL (board --dial)."""
    return f"DIALING {url[5:]}" if url.startswith("dial ") else f"LISTENING {url}"


#: the sim-only options and what they are when not given
_SIM_ONLY = {"name": None, "config_file": None, "rate": None, "channels": None,
             "clock_offset_us": None, "clock_skew_ppm": None, "clock_drift_ppm_per_s": None,
             "clock_ref_ns": None, "reset_at": None, "count": 1}  # fmt: skip


def _board_file(args: argparse.Namespace) -> int:
    """``board --file BOARDFILE``: the board file's firmware on CPython or under MicroPython,
    every part simulated (missing_link.virtual.boardfile, .mpyboard), listening or dialing.
    Bad input (the file, --absent, --flash, a missing node) is ConfigError: one line, exit 2
    (main.py)."""
    from ..deploy.boardfile import load_board_file
    from ..errors import ConfigError

    if args.flash and args.seed is not None:
        raise ConfigError(
            "--seed goes without --flash: a board with a flash keeps its chip id there"
        )
    given = [k for k, default in _SIM_ONLY.items() if getattr(args, k) != default]
    if given:
        flag = "--" + given[0].replace("_", "-")
        raise ConfigError(f"{flag} goes with --sim, not --file")
    bf = load_board_file(args.file)
    board = dict(bf.board)
    names = [t["name"] for t in bf.transducers]
    absent = [a.strip() for a in (args.absent or "").split(",") if a.strip()]
    unknown = [a for a in absent if a not in names]
    if unknown:
        raise ConfigError(
            f"--absent {unknown[0]}: no such part in {args.file} (parts: {', '.join(names)})"
        )
    flash = Path(args.flash) if args.flash else None
    if flash is not None:
        if flash.exists() and not flash.is_dir():
            raise ConfigError(f"--flash {flash}: not a directory")
        flash.mkdir(parents=True, exist_ok=True)
    key = board.get("link", {}).get("key_file")
    if key and (flash is None or not (flash / key).is_file()):
        where = f"{flash / key}" if flash is not None else f"DIR/{key} and give --flash DIR"
        raise ConfigError(
            f"{args.file}: its link is signed (key_file {key}): the key goes in the board's "
            f"flash: missing-link key new {where}"
        )
    if key and args.listen in ("pty", "pty://"):
        raise ConfigError(f"{args.file}: its link is signed: serve it on tcp (or unix), not a pty")
    world = _world(args, board)
    with tempfile.TemporaryDirectory(prefix="ml-flash-") as scratch:
        return _serve_board_file(args, board, bf.path, flash or Path(scratch), absent, world)


def _world(args: argparse.Namespace, board: dict[str, Any]) -> Any:
    """The world file's WorldSpec (the default world without one; None for ``--world none``),
    checked against the board file: a mistake is a ConfigError naming the file and the key."""
    from ..errors import ConfigError
    from ..world.robot import build
    from ..world.spec import WorldSpec
    from ..world.worldfile import parse

    if args.world == "none":
        if args.world_control:
            raise ConfigError("--world-control needs a world: not --world none")
        return None
    if args.world is None:
        spec = WorldSpec()
    else:
        try:
            text = Path(args.world).read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as e:
            raise ConfigError(f"--world {args.world}: cannot read it ({e})") from None
        spec = parse(text, args.world)
    build(spec, board)  # (its parts against the board file's, now: one line, exit 2)
    return spec


def _serve_board_file(
    args: argparse.Namespace,
    board: dict[str, Any],
    path: Path,
    flash: Path,
    absent: list[str],
    world: Any,
) -> int:
    from ..errors import MissingLinkError
    from ..virtual.boardfile import chip_id

    url, dial = args.dial or args.listen, bool(args.dial)
    try:
        chip = chip_id(flash if args.flash else None, args.seed or 0)
        if args.runtime == "micropython":
            from ..deploy.flashdir import prepare
            from ..virtual.mpyboard import MicroPythonBoard
            from ..virtual.world_mpy import NodeWorld

            if args.flash:  # (the board starts from its flash, as a board does: it takes updates)
                prepare(path, flash, lambda t: print(f"missing-link: {t}", file=sys.stderr))
            kept = flash if args.flash else None
            node_world = None
            if world is not None:  # (beside the firmware, in this process: world_mpy.py)
                node_world = NodeWorld(world, board, args.seed or 0, frozenset(absent))
            server: Any = MicroPythonBoard(
                path, url, kept, absent, dial=dial, chip=chip, world=node_world
            )
        elif args.runtime == "avr":
            server = _avr_board(path, url, dial, flash if args.flash else None, absent, chip)
            if world is not None:  # (beside simavr, in this process: world_avr.py)
                server.world_hand = _avr_world(server, world, board, args.seed or 0, absent)
        else:
            from ..virtual.boardfile import BoardFileBoard

            server = BoardFileBoard(
                board, url, flash, absent, dial=dial, chip=chip, world=world, seed=args.seed or 0
            )
    except MissingLinkError:
        raise  # (bad input: exit 2; cannot listen, did not start: exit 1; main.py says it)
    except Exception as e:  # noqa: BLE001 - the firmware failed at boot: one line, exit 1
        print(f"missing-link: error: {args.file}: the firmware stopped: {_why(e)}", file=sys.stderr)
        return EXIT_FAIL

    def stop(signum: int, frame: object) -> None:
        server.stop()

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    control = _world_control(args, server)
    print(_ready(server.url), flush=True)
    if control is not None:
        print(f"WORLD {control.url}", flush=True)
    try:
        server.serve_forever()
    except MissingLinkError as e:
        print(f"missing-link: error: {args.file}: {e}", file=sys.stderr)
        return EXIT_FAIL
    except Exception as e:  # noqa: BLE001 - the firmware stopped: said in one line, exit 1
        print(f"missing-link: error: {args.file}: the firmware stopped: {_why(e)}", file=sys.stderr)
        return EXIT_FAIL
    finally:
        if control is not None:
            control.close()
    return 0


def _world_control(args: argparse.Namespace, server: Any) -> Any:
    """The world's control endpoint (virtual/worldctl.py) when --world-control asks for one."""
    if not args.world_control:
        return None
    hand = getattr(server, "world_hand", None)
    if hand is None:
        server.stop()
        raise ConfigError(f"--world-control: the {args.runtime or 'cpython'} runtime has no world")
    from ..virtual.worldctl import WorldControl

    try:
        return WorldControl(hand, args.world_control)
    except BaseException:
        server.stop()
        raise


def _avr_board(
    path: Path, url: str, dial: bool, flash: Path | None, absent: list[str], chip: bytes
) -> Any:
    """The board file's C firmware in simavr (deploy/avrsim.py, virtual/avrboard.py); its
    board.id from the chip id; with --flash its EEPROM kept there."""
    from ..deploy.avrsim import build
    from ..deploy.boardfile import load_board_file
    from ..virtual.avrboard import AvrBoard

    if dial:
        raise ConfigError("--runtime avr: an AVR board's link is its UART: serve it with --listen")
    sim = build(load_board_file(path), "avr-" + chip.hex()[:12], absent)
    return AvrBoard(sim.command(flash / "eeprom.bin" if flash else None), url)


def _avr_world(server: Any, spec: Any, board: dict[str, Any], seed: int, absent: list[str]) -> Any:
    """The world beside the AVR in simavr, driving the rig through its control lines, from
    the simulation's time now."""
    from ..virtual.world_avr import AvrWorld, sim_us
    from ..virtual.worldlink import WorldLink
    from ..world.world import World

    try:
        world = World(spec, board, sim_us(server.ctl), seed)
        hand = AvrWorld(WorldLink(world, board, absent), server.ctl_lines,
                        board.get("transducers", []), absent, server.ctl_post)  # fmt: skip
        server.on_tick = hand.answer  # (the rig's answers at each tick's time)
        hand.start()
    except BaseException:
        server.close()
        raise
    return hand


def _why(e: BaseException) -> str:
    """An exception in one line, with where it was raised (the board file's firmware)."""
    tb = e.__traceback__
    while tb is not None and tb.tb_next is not None:
        tb = tb.tb_next
    where = f" ({Path(tb.tb_frame.f_code.co_filename).name}:{tb.tb_lineno})" if tb else ""
    return f"{type(e).__name__}: {e}{where}"


def _serve_many(args: argparse.Namespace, extra: dict[str, Any]) -> int:
    """``board --count N``: N boards in this one process (a thread each), named NAME_0.. and
    seeded SEED.., one LISTENING line each: benchmarks load the host, not N board processes."""
    from ..virtual import BoardServer, make_sim

    if not args.dial and not (args.listen.startswith("tcp://") and args.listen.endswith(":0")):
        print("missing-link: error: --count needs --listen tcp://HOST:0 or --dial", file=sys.stderr)
        return EXIT_USAGE
    base = extra.pop("name", None) or args.sim
    servers = []
    for k in range(args.count):
        runtime = make_sim(args.sim, seed=args.seed + k, name=f"{base}_{k}", **extra)
        servers.append(BoardServer(runtime, args.dial or args.listen, dial=bool(args.dial)))
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
        print(_ready(s.url), flush=True)
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
