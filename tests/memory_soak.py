"""A board file's MicroPython firmware for simulated minutes, in a board's heap, with a host that
takes every byte (tests/test_memory.py).

The firmware runs under the real MicroPython interpreter in the simulator (host.mjs) with
``--heap`` (a board's fixed heap, heap.mjs) and ``--fast`` (simulated time, fastclock.mjs:
the clock jumps over what the firmware sleeps and moves on by what its steps cost), so ten
simulated minutes take a minute or so; ``--lead-ms`` keeps the simulation at most that far ahead
of its host.  The host is this library's own: :class:`~missing_link.host.board.Board` over TCP,
the handshake, every SIF decoded into samples (``SampleDecoder``), clock exchanges, a fresh
host map for aligned sampling (host ns = board µs x 1000: the grid's instants are whole
multiples of a period in board µs), the actuators commanded, and at the end the board's own
figures (``a2jMemory``, ``a2jAlignInfo``, ``a2jDebug``).  Nothing is stubbed: the firmware's
loop, its drivers against the simulated parts, the SIF encoding and the link all run.
"""

from __future__ import annotations

import json
import queue
import shutil
import struct
import subprocess
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from missing_link.daemon.session.board_memory import parse_memory
from missing_link.daemon.session.status import MemoryStatus
from missing_link.host.board import Board
from missing_link.host.samples import SampleDecoder
from missing_link.transport import open_transport

from .helpers import FirmwareSim, pump_lines

MAP_EVERY_US = 2_000_000  # a fresh host map this often (board µs): it vouches for 10 s
#: the host's turn, in board µs: a clock exchange, a map when due, its commands.  Its pace is
#: the simulation's, not the machine's (the same traffic per simulated second however loaded
#: the host is), the daemon's busiest steady probing (timesync ClockSync fast_interval)
TURN_US = 50_000
POLL_S = 0.002  # how often the host looks at the simulated clock, waiting for its next turn


class FastSim(FirmwareSim):
    """The simulator with a board's heap and simulated time (host.mjs --heap --fast)."""

    def __init__(self, board_file: Path, heap: int, lead_ms: int = 500, scale: float = 1.0):
        if shutil.which("node") is None:
            raise RuntimeError("node is required: run `make node`")
        cmd = ["node", str(self.HOST), str(board_file), "--heap", str(heap), "--fast"]
        cmd += ["--lead-ms", str(lead_ms), "--cpu-scale", str(scale)]
        self.proc = subprocess.Popen(
            cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
            text=True, cwd=self.ROOT,
        )  # fmt: skip
        self._lines: queue.Queue[str | None] = queue.Queue()
        pump_lines(self.proc, self._lines)
        self.stderr: list[str] = []  # (read as it comes: a full pipe would stall the simulation)
        pump = threading.Thread(target=self._pump_stderr, daemon=True)
        pump.start()
        first = self._lines.get(timeout=60)
        if first is None or not first.startswith("LISTEN "):
            self.proc.wait(10)
            pump.join(10)  # (all it said, before it is quoted)
            raise RuntimeError(f"firmware simulator did not start: {first!r} {self._why()}")
        _, port, self.ident = first.split(" ", 2)
        self.url = f"tcp://127.0.0.1:{port}"
        self._lock = threading.Lock()

    def _why(self) -> str:
        """What the simulator said when it stopped, without emscripten's refused growths of
        the heap (--heap fixed it)."""
        return "".join(ln for ln in self.stderr if "grow" not in ln.lower())[-2000:]

    def _pump_stderr(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            self.stderr.append(line)

    def figure(self, what: str) -> Any:
        """{"sim": what}: "time" (simulated µs since the start), "held" (whether --lead-ms
        holds the simulation for the host's bytes) or "gc" (the collections)."""
        assert self.proc.stdin is not None
        with self._lock:
            self.proc.stdin.write(json.dumps({"sim": what}) + "\n")
            self.proc.stdin.flush()
            line = self._lines.get(timeout=30)
        if line is None or not line.startswith("OK "):
            raise RuntimeError(f"simulator: {line!r}")
        return json.loads(line[3:])


@dataclass
class SoakResult:
    board_us: int  #: simulated µs the host saw pass on the board's clock
    samples: Counter[str] = field(default_factory=Counter)  #: decoded samples per transducer
    valid: Counter[str] = field(default_factory=Counter)  #: ... with a value (not N/A)
    maps: list[int] = field(default_factory=list)  #: board µs by when each host map was in
    memory: MemoryStatus = field(default_factory=MemoryStatus)
    align: tuple[int, ...] = ()  #: a2jAlignInfo
    debug: str = ""  #: what a2jDebug had at the end
    commands: int = 0


def soak(
    sim: FastSim,
    seconds: float,
    aligned: Iterable[str] = (),
    act: Callable[[Board, int], int] | None = None,
) -> SoakResult:
    """Serve the board as a host for ``seconds`` of its clock; ``aligned``: transducers put on
    the host-time grid; ``act(board, turn)``: the host's commands each turn (-> how many)."""
    board = Board(open_transport(sim.url), timeout=30.0)
    try:
        board.handshake()
        decoder = SampleDecoder(board.name, board.transducers or [])
        names = {t.id: t.name for t in board.transducers or []}
        res = SoakResult(0)

        def on_sif(ev: Any, host_rx: float) -> None:
            got = decoder.decode(ev, host_rx)
            if got:
                res.samples[names[ev.cmd]] += 1
                res.valid[names[ev.cmd]] += any(s.value is not None for s in got)

        board.on_sif(None, on_sif)
        start = board.clock_exchange(30).t3
        aligned = list(aligned)
        turn = 0
        while True:
            now = board.clock_exchange(30).t3  # (bytes from the host: the simulation goes on)
            if aligned and (not res.maps or now - res.maps[-1] >= MAP_EVERY_US):
                if not res.maps:  # (aligned first: the grid holds from the map on)
                    board.configure({f"{name}.aligned": True for name in aligned})
                board.call_ok("a2jHostMap", struct.pack("<Qqi", now, now * 1000, 0))
                # (the board has it by its time at the next exchange: the simulation runs
                # on meanwhile, up to --lead-ms)
                res.maps.append(board.clock_exchange(30).t3)
            if act is not None:
                res.commands += act(board, turn)
            turn += 1
            if now - start >= seconds * 1e6:
                break
            wait_turn(sim, TURN_US)
        res.board_us = now - start
        res.memory = parse_memory(board.call_ok("a2jMemory"))
        res.align = struct.unpack("<BIIII", board.call_ok("a2jAlignInfo"))
        res.debug = board.call_ok("a2jDebug").decode(errors="replace")
        return res
    finally:
        board.close()


def wait_turn(sim: FastSim, us: int) -> None:
    """Until the simulation has gone ``us`` on, or as far as it goes without the host: it runs
    at most --lead-ms past the host's last bytes, and a host slower than the simulation (a
    loaded machine) may find it there already; waiting for more was a deadlock."""
    until = int(sim.figure("time")) + us
    while int(sim.figure("time")) < until and not sim.figure("held"):
        time.sleep(POLL_S)


def grid_hits(
    spans: Iterable[tuple[int, int]], periods_us: Iterable[int], maps: list[int], life_us: int
) -> list[tuple[int, int, int]]:
    """The spans (from, to] (board µs) that hold an instant of a grid (whole multiples of a
    period, phase 0) while a host map vouched for it: at most ``life_us`` after one pushed
    (board µs by when the board had it, ``maps``).  (An instant at a span's start was measured
    before it: the step began with it.)"""
    hits = []
    periods = list(periods_us)
    for a, b in spans:
        for p in periods:
            k = (a // p + 1) * p  # the first instant after a
            if k <= b and any(0 <= k - m <= life_us for m in maps):
                hits.append((a, b, k))
    return hits


def runs_in(board_file: Path, heap: int, aligned: Iterable[str], seconds: float = 20) -> bool:
    """Whether the board file's firmware boots and serves a host for ``seconds`` of its clock
    in a heap of ``heap`` bytes, without MemoryError."""
    try:
        sim = FastSim(board_file, heap)
    except RuntimeError:  # (it did not boot)
        return False
    try:
        res = soak(sim, seconds, aligned)
    except Exception:  # noqa: BLE001 - a firmware that ran out stops answering: a no
        return False
    finally:
        sim.close()
    return "MemoryError" not in "".join(sim.stderr) and "memory" not in res.debug.lower()


def smallest_heap(board_file: Path, aligned: Iterable[str], lo: int, hi: int) -> int:
    """The smallest heap (within 1 KiB) the board file runs in (runs_in), by bisection between
    ``lo`` (too small) and ``hi`` (enough): how deploy/heap.py's WORKING was measured."""
    aligned = list(aligned)
    while hi - lo > 1024:
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if runs_in(board_file, mid, aligned) else (mid, hi)
    return hi
