"""``info``, ``call``, ``listen``, ``sync``: one board, talked to directly (``info`` and ``call``
through the daemon that holds it, when one does: remote.py)."""

from __future__ import annotations

import argparse
import sys
import threading
import time
from typing import TYPE_CHECKING, Any

from ..errors import ConfigError, payload_text
from .common import EXIT_FAIL, EXIT_USAGE, emit_json, error, open_url
from .remote import RemoteBoard, reach

if TYPE_CHECKING:  # (what only listen and sync use is imported there: a call loads less)
    from ..descriptors import Transducer
    from ..host.board import Board
    from ..host.samples import Sample
    from ..j2a import SifReceived


def cmd_info(args: argparse.Namespace) -> int:
    with reach(args.url, args.timeout) as board:
        if args.json:
            emit_json({**board.describe(), **_memory(board)})
            return 0
        kind = (
            "original (Part 1) board"
            if board.is_original
            else f"J2A {board.properties['j2a.version']} board"
        )
        via = " (through the daemon that holds it)" if isinstance(board, RemoteBoard) else ""
        print(f"{board.name} at {board.url}: {kind}{via}")
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


def _memory(board: Board | RemoteBoard) -> dict[str, Any]:
    """{"memory": the board's own figures (a2jMemory, daemon/session/board_memory.py)} when it has
    them."""
    from ..daemon.session.board_memory import FUNCTION, parse_memory

    if FUNCTION not in board.functions:
        return {}
    result = board.call(FUNCTION, b"", timeout=None)
    if result.code != 0:
        return {"memory": f"{FUNCTION} returned {result.code:#04x}"}
    figures = parse_memory(result.payload)
    return {"memory": figures.problem or figures.to_json()}


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
    if args.value is not None and args.hex:
        print("missing-link: error: give --hex or --value, not both", file=sys.stderr)
        return EXIT_USAGE
    with reach(args.url, args.timeout, describe=args.value is not None) as board:
        payload = args.hex if args.value is None else value_payload(board, args.name, args.value)
        t = None if args.value is None else actuator_of(board, args.name)
        acted = None if t is None else (t, str(args.value))
        result = board.call(args.name, payload, timeout=args.timeout)
    if args.json:
        emit_json(
            {
                "function": args.name,
                "code": result.code,
                "ok": result.ok,
                "payload": result.payload.hex(),
            }
        )
    else:
        text = payload_text(result.payload)
        print(f"return {result.code:#04x} ({result.code})  payload {len(result.payload)} bytes")
        if result.payload:
            print(f"  hex   {result.payload.hex(' ')}")
            if text:
                print(f"  text  {text}")
        print(f"  means {meaning(args.name, result.code, text, acted)}")
    if result.code != SUCCESS_CODES.get(args.name, 0) and not args.any_code:
        said = payload_text(result.payload)
        print(
            f"missing-link: error: {args.name} returned {result.code:#04x}"
            + (f": {said}" if said else "")
            + " (not OK; --any-code accepts every return value)",
            file=sys.stderr,
        )
        return EXIT_FAIL
    return 0


#: the reply opcodes a board's firmware answers with instead of a function's (spec 1.5)
ERROR_FRAMES = {
    0xF0: "no such function on the board (index out of its table)",
    0xF2: "the board timed out receiving the request (or it was cut)",
    0xF3: "the board saw a bad checksum",
    0xF4: "the board saw a bad escape",
}


def meaning(function: str, code: int, text: str, acted: tuple[Transducer, str] | None) -> str:
    """What a call's return value says (spec 1.5: 0 OK by convention, 0xFF failure, 0xF0..F4
    the firmware's error frames), with what a ``--value`` set (``acted``: the actuator and
    the value as given)."""
    if code == SUCCESS_CODES.get(function, 0):
        if acted is None:
            return "OK" + (" (a2jEcho's own code: the payload came back)" if code else "")
        t, value = acted
        shown = value
        if t.scaled:  # (the servo's 40 is 28.35 deg)
            shown = f"{value} ({t.in_unit(float(value)):.4g} {t.unit})"
        elif t.unit:
            shown = f"{value} {t.unit}"
        return f"OK: {t.name} took {shown}, as send() of its command topic would send it"
    if code in ERROR_FRAMES:
        return f"not done: {ERROR_FRAMES[code]}"
    if code == 0xFF:
        return "refused: the function's failure" + (f" ({text})" if text else "")
    return f"{function}'s own return value {code} (not OK by convention: 0 is)"


def actuator_of(board: Board | RemoteBoard, function: str) -> Transducer | None:
    """The actuator whose ``call=`` is ``function`` (``--value``'s)."""
    for t in board.transducers or []:
        if t.call == function:
            return t
    return None


def value_payload(board: Board | RemoteBoard, function: str, text: str) -> bytes:
    """``--value``: one value packed as the data type of the actuator whose ``call=`` is
    ``function`` (the same bytes ``send(topic, value)`` makes), checked against it."""
    for t in board.transducers or []:
        if t.call == function:
            try:
                value: int | float = float(text) if t.dtype in ("float", "double") else int(text)
            except ValueError:
                raise ConfigError(f"--value {text!r}: {t.name} takes a {t.dtype}") from None
            try:
                return t.pack_command(value)  # (its type's range: the daemon's own check)
            except ValueError as e:
                raise ConfigError(f"--value {text!r}: {e}") from None
    callers = sorted(str(t.call) for t in board.transducers or [] if t.call)
    raise ConfigError(
        f"--value: no actuator of {board.name} is called through {function} "
        f"(actuator functions: {', '.join(callers) or 'none'}); give --hex bytes"
    )


def format_sample(s: Sample, unit: str | None) -> str:
    value = "N/A" if s.value is None else f"{s.value}{(' ' + unit) if unit else ''}"
    lost = f"  (lost {s.lost} SIFs before)" if s.lost else ""
    where = f"{s.board}/{s.transducer}[{s.channel}]"
    return f"{s.host_rx:14.6f}  {where} = {value}  @board {s.board_us} us{lost}"


class _Printer:
    """``listen``'s SIF handler (on the board's reading thread): decoded samples, or raw SIFs
    from a board without descriptors, as lines or JSON objects, until ``--count``."""

    def __init__(self, args: argparse.Namespace, board: Board, wanted: set[str]) -> None:
        from ..host.samples import SampleDecoder

        self.args = args
        self.transducers = board.transducers or []
        self.decoder = SampleDecoder(board.name, self.transducers)
        self.units = {t.name: t.unit for t in self.transducers}
        self.wanted = wanted
        self.done = threading.Event()
        self.count = 0
        self._lock = threading.Lock()

    def _said(self, sif: SifReceived, now: float) -> tuple[list[str], list[dict[str, object]]]:
        if not self.transducers:
            line = f"{now:14.6f}  sif cmd={sif.cmd} seq={sif.seq} lost={sif.lost}"
            raw = {"cmd": sif.cmd, "seq": sif.seq, "lost": sif.lost, "payload": sif.payload.hex()}
            return [f"{line} {sif.payload.hex()}"], [{**raw, "host_rx": now}]
        samples = [
            s
            for s in self.decoder.decode(sif, now, keep_missing=self.args.missing)
            if not self.wanted or s.transducer in self.wanted
        ]
        lines = [format_sample(s, self.units.get(s.transducer)) for s in samples]
        return lines, [s.to_json() for s in samples]

    def on_sif(self, sif: SifReceived, now: float) -> None:
        import json

        args = self.args
        with self._lock:
            if self.done.is_set():
                return
            lines, objs = self._said(sif, now)
            for line, obj in zip(lines, objs, strict=True):
                if args.count and self.count >= args.count:
                    self.done.set()
                    return
                print(json.dumps(obj) if args.json else line, flush=False)
                self.count += 1
            sys.stdout.flush()
            if args.count and self.count >= args.count:
                self.done.set()


def cmd_listen(args: argparse.Namespace) -> int:
    with open_url(args) as board:
        units = {t.name: t.unit for t in board.transducers or []}
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
        printer = _Printer(args, board, wanted)
        done = printer.done
        board.on_sif(None, printer.on_sif)
        deadline = time.monotonic() + args.duration if args.duration else None
        while not done.is_set() and board.alive:
            if deadline is not None and time.monotonic() >= deadline:
                break
            done.wait(0.1)
        done.set()
        if not board.alive:
            return error(f"{board.url}: link lost", EXIT_FAIL)
    return 0


def cmd_sync(args: argparse.Namespace) -> int:
    from ..errors import CallTimeout
    from ..timesync.sync import ClockSync, SyncOptions

    if args.uart_baud and not args.url.removeprefix("spy+").startswith("serial://"):
        print(
            "missing-link: error: --uart-baud describes a UART link (serial://); "
            f"{args.url} is not one, and its bytes do not take UART time",
            file=sys.stderr,
        )
        return EXIT_USAGE
    byte_ns = 10e9 / args.uart_baud if args.uart_baud else 0.0
    with open_url(args) as board:
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
                    emit_json(st)
                else:
                    print(format_sync(st), flush=True)
        if not board.alive:
            return error(f"{board.url}: link lost", EXIT_FAIL)
    return 0


def format_sync(st: dict[str, Any]) -> str:
    head = f"{st['t_s']:7.1f}s {st['sync_state']:<9}"
    if "offset_us" not in st:
        return f"{head} no estimate yet (exchanges {st['sync_exchanges']}, lost {st['sync_lost']})"
    return (
        f"{head} offset {st['offset_us']:+.3f} µs  skew {st['skew_ppm']:+8.3f} ppm"
        f"  bound ±{st['bound_us']:.1f} µs (hard)  est ±{st['est_error_us']:.1f} µs"
        f"  rtt {st['sync_rtt_us']:.0f} µs (min {st['sync_min_rtt_us']:.0f})"
        f"  every {st['sync_interval_ms']:.0f} ms  exchanges {st['sync_exchanges']}"
        f" lost {st['sync_lost']}"
    )
