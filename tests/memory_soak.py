"""A board file's MicroPython firmware for simulated minutes, in a board's heap, with a host that
takes every byte (tests/test_memory.py).

The firmware runs under the real MicroPython interpreter in the simulator (host.mjs) with
``--heap`` (a board's fixed heap, heap.mjs), ``--fast`` (simulated time, fastclock.mjs: the
clock jumps over what the firmware sleeps and moves on by what its work costs on a Pico,
simcost.py) and ``--lockstep`` (lockstep.mjs: it runs only when its host says, and takes the
host's bytes only when the host says it sent them), so ten simulated minutes take a minute or
so and the same host gives the same run every time, on a quiet machine or a busy one.  The host
is this library's own: :class:`~missing_link.host.board.Board` over TCP (:class:`LockstepHost`:
its blocking calls run the simulation until their reply is in; its clock is the simulation's),
the handshake, every SIF decoded into samples (``SampleDecoder``), clock exchanges, a fresh
host map for aligned sampling (host ns = board µs x 1000: the grid's instants are whole
multiples of a period in board µs), the actuators commanded, and at the end the board's own
figures (``a2jMemory``, ``a2jAlignInfo``, ``a2jDebug``).  Nothing is stubbed: the firmware's
loop, its drivers against the simulated parts, the SIF encoding and the link all run.
"""

from __future__ import annotations

import json
import shutil
import struct
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable
from concurrent.futures import Future
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

from missing_link.daemon.session.board_memory import parse_memory
from missing_link.daemon.session.status import MemoryStatus
from missing_link.host.board import Board
from missing_link.host.samples import SampleDecoder
from missing_link.j2a import SifReceived
from missing_link.testing import FakeClock
from missing_link.transport import Transport, open_transport
from missing_link.transport.base import Received
from missing_link.virtual.world_mpy import NodeWorld

from .helpers import FirmwareSim, start_with_lines

T = TypeVar("T")
MAP_EVERY_US = 2_000_000  # a fresh host map this often (board µs): it vouches for 10 s
#: the host's turn, in board µs: a clock exchange, a map when due, its commands.  Its pace is
#: the simulation's, not the machine's (the same traffic per simulated second however loaded
#: the host is), the daemon's busiest steady probing (timesync ClockSync fast_interval)
TURN_US = 50_000
#: how far (board µs) the simulation runs at a time while the host waits for a reply: the
#: host's reaction time (it answers within a step of the board's anyway)
QUANTUM_US = 1_000
POLL_S = 0.002  # how often a host in real time (--lead-ms) looks at the simulated clock
REPLY_S = 60.0  # how long the host waits for the bytes a run sent (a bound on a hang)
#: simulated µs the board is up before its host connects (a USB link alone takes longer to come
#: up): the rover's VL53L0X calibrates at boot in one loop, a single step on this port, which
#: collects only between steps; with the host's first call in that step too it needs more than
#: a Pico's heap here, where a board collects as it goes (docs/hardware.md, "Memory")
BOOT_US = 500_000


class FastSim(FirmwareSim):
    """The simulator with a board's heap and simulated time (host.mjs --heap --fast), in
    lockstep with its host (``lead_ms`` None) or ``lead_ms`` ahead of it at most."""

    def __init__(
        self,
        board_file: Path,
        heap: int,
        lead_ms: int | None = None,
        seed: int = 1,
        world: NodeWorld | None = None,
    ) -> None:
        if shutil.which("node") is None:
            raise RuntimeError("node is required: run `make node`")
        cmd = ["node", str(self.HOST), str(board_file), "--heap", str(heap), "--fast"]
        cmd += ["--lockstep"] if lead_ms is None else ["--lead-ms", str(lead_ms)]
        cmd += ["--seed", str(seed)] + (world.node_args() if world else [])
        self.proc, self._lines = start_with_lines(
            cmd, cwd=self.ROOT, pass_fds=world.pass_fds if world else ()
        )
        if world is not None:  # (beside the firmware, in this process: world_mpy.py)
            world.started()
        self.stderr: list[str] = []  # (read as it comes: a full pipe would stall the simulation)
        pump = threading.Thread(target=self._pump_stderr, daemon=True)
        pump.start()
        first = self._lines.get(timeout=60)
        if first is None or not first.startswith("LISTEN "):
            self.proc.wait(10)
            pump.join(10)  # (all it said, before it is quoted)
            raise RuntimeError(f"firmware simulator did not start: {first!r} {self.why()}")
        _, port, self.ident = first.split(" ", 2)
        self.url = f"tcp://127.0.0.1:{port}"
        self._lock = threading.Lock()

    def why(self) -> str:
        """What the simulator said when it stopped, without emscripten's refused growths of
        the heap (--heap fixed it)."""
        return "".join(ln for ln in self.stderr if "grow" not in ln.lower())[-2000:]

    def _pump_stderr(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            self.stderr.append(line)

    def figure(self, what: str) -> Any:
        """{"sim": what}: "time" (simulated µs since the start), "held" (whether --lead-ms
        holds the simulation for the host's bytes) or "gc" (the collections: "log" [from, to,
        kind] board µs, "us" what each took, and with a heap "heap" [bytes in use as it began,
        bytes live after])."""
        return self._ask({"sim": what}, 30)

    def run(self, us: int, rx: list[int]) -> dict[str, Any]:
        """--lockstep: ``us`` simulated µs on, once its host's connections have sent ``rx``
        bytes each (lockstep.mjs) -> {"now": µs, "tx": [bytes sent to each], "stopped": bool}."""
        out: dict[str, Any] = self._ask({"sim": "run", "us": us, "rx": rx}, REPLY_S)
        return out

    def _ask(self, req: object, timeout: float) -> Any:
        assert self.proc.stdin is not None
        with self._lock:
            self.proc.stdin.write(json.dumps(req) + "\n")
            self.proc.stdin.flush()
            line = self._lines.get(timeout=timeout)
        if line is None or not line.startswith("OK "):
            raise RuntimeError(f"simulator: {line!r} {self.why()}")
        return json.loads(line[3:])


class CountingTransport(Transport):
    """A transport that counts what its host wrote and what its reader has taken in (the bytes
    of a read, once the reader comes back for more: the link engine handles what one read
    brought before it reads again, replies resolved and SIFs handed on)."""

    def __init__(self, inner: Transport) -> None:
        self.inner = inner
        self.url = inner.url
        self.wakes_on_close = inner.wakes_on_close
        self.written = 0
        self.taken = 0  #: bytes the reader has handled
        self._read = 0  # bytes the reader has been handed
        self._cond = threading.Condition()

    def read(self, timeout: float | None) -> bytes:
        return self.read_stamped(timeout)[0]

    def read_stamped(self, timeout: float | None) -> Received:
        with self._cond:
            self.taken = self._read
            self._cond.notify_all()
        got = self.inner.read_stamped(timeout)
        with self._cond:
            self._read += len(got[0])
        return got

    def wait_taken(self, n: int, timeout: float) -> bool:
        """Until the reader has handled ``n`` bytes (False: not within ``timeout`` s)."""
        with self._cond:
            return self._cond.wait_for(lambda: self.taken >= n, timeout)

    def write(self, data: bytes) -> None:
        self.inner.write(data)
        self.written += len(data)

    def poke(self) -> None:
        self.inner.poke()

    def close(self) -> None:
        self.inner.close()


class LockstepHost:
    """A :class:`~missing_link.host.board.Board` on a simulation in lockstep (FastSim with no
    lead): the simulation stands still while the host works, and runs when the host waits,
    with every byte the host wrote so far, ``QUANTUM_US`` at a time until the reply is in (the
    board's link waits so, its one place of waiting); ``run`` lets it run on while the host
    has nothing to say.  After each run the host has handled every byte it sent.  The board's
    clock (call timeouts, clock exchanges' host stamps) is the simulation's.  So the same
    host gives the same run every time, whatever else runs on the machine."""

    def __init__(self, sim: FastSim, timeout: float = 30.0) -> None:
        self.sim = sim
        self.now_us = int(sim.run(BOOT_US, [])["now"])
        self.clock = FakeClock()
        self.transport = CountingTransport(open_transport(sim.url))
        self.board = Board(self.transport, timeout=timeout, clock=self.clock)
        self.board.link.wait = self._wait  # type: ignore[method-assign]

    def run(self, us: int) -> None:
        """The simulation ``us`` µs on, with what the host wrote; back once the host has
        handled what it sent meanwhile."""
        got = self.sim.run(max(0, us), [self.transport.written])
        if got["stopped"]:
            raise RuntimeError(f"the firmware stopped: {self.sim.why()}")
        self.clock.advance((got["now"] - self.now_us) / 1e6)
        self.now_us = got["now"]
        sent = got["tx"][0] if got["tx"] else 0
        if not self.transport.wait_taken(sent, REPLY_S):
            raise RuntimeError(f"the host did not take the {sent} bytes sent")

    def run_until(self, us: int) -> None:
        """The simulation on to simulated µs ``us`` (since its start), if not there yet."""
        self.run(us - self.now_us)

    def _wait(self, fut: Future[T], timeout: float | None) -> T:
        while not fut.done():
            self.run(QUANTUM_US)
        return fut.result()

    def close(self) -> None:
        self.board.close()


@dataclass
class SoakResult:
    board_us: int  #: simulated µs the host saw pass on the board's clock
    samples: Counter[str] = field(default_factory=Counter)  #: decoded samples per transducer
    valid: Counter[str] = field(default_factory=Counter)  #: ... with a value (not N/A)
    stamps: dict[str, list[int]] = field(default_factory=dict)  #: board µs of each sample
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
    on_sif: Callable[[SifReceived], None] | None = None,
) -> SoakResult:
    """Serve the board as a host in lockstep for ``seconds`` of its clock; ``aligned``:
    transducers put on the host-time grid; ``act(board, turn)``: the host's commands each turn
    (-> how many); ``on_sif``: each SIF as it came (the sample stream)."""
    host = LockstepHost(sim)
    board = host.board
    try:
        board.handshake()
        decoder = SampleDecoder(board.name, board.transducers or [])
        names = {t.id: t.name for t in board.transducers or []}
        res = SoakResult(0)

        def take(ev: Any, host_rx: float) -> None:
            got = decoder.decode(ev, host_rx)
            if on_sif is not None:
                on_sif(ev)
            if got:
                res.stamps.setdefault(names[ev.cmd], []).append(got[0].board_us)
                res.samples[names[ev.cmd]] += 1
                res.valid[names[ev.cmd]] += any(s.value is not None for s in got)

        board.on_sif(None, take)
        start = board.clock_exchange(30).t3
        aligned = list(aligned)
        turn = 0
        while True:
            due = host.now_us + TURN_US
            now = board.clock_exchange(30).t3
            if aligned and (not res.maps or now - res.maps[-1] >= MAP_EVERY_US):
                if not res.maps:  # (aligned first: the grid holds from the map on)
                    board.configure({f"{name}.aligned": True for name in aligned})
                board.call_ok("a2jHostMap", struct.pack("<Qqi", now, now * 1000, 0))
                res.maps.append(board.clock_exchange(30).t3)  # (the board has it by then)
            if act is not None:
                res.commands += act(board, turn)
            turn += 1
            if now - start >= seconds * 1e6:
                break
            host.run_until(due)
        res.board_us = now - start
        res.memory = parse_memory(board.call_ok("a2jMemory"))
        res.align = struct.unpack_from("<BIIII", board.call_ok("a2jAlignInfo"))
        res.debug = board.call_ok("a2jDebug").decode(errors="replace")
        return res
    finally:
        host.close()


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
