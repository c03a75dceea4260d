"""The world beside the firmware, not in it (issue 47.6): the rover's MicroPython firmware in a
Raspberry Pi Pico's heap, in simulated time and in lockstep with its host (memory_soak.py:
host.mjs --heap --fast --lockstep), served the same way with its world beside it and with
none, holds the same live data, allocates the same, and keeps the same sample timing.

The world runs in this process (world_mpy.py) and reaches the firmware's devices between its
steps with small integers only; the simulated clock moves on by what the firmware's own work
costs (simcost.py), never by the world's.  The world puts the rover 1 m before a wall, where
the simulator's parts put their target without a world (pin_devices.py, i2c_devices.py), so
the firmware does the same work in both: what differs is only what its sensors read.  Same
host, same commands, same simulated seconds: the figures are statements about the firmware, on
a quiet machine or a busy one.

Which figures: the run is chaotic in where things land, so a figure held here is one that does
not follow where they land.  A few allocations more or less (what the firmware makes of what
it reads: a fix's digits) move a collection by a loop turn; a periodic driver whose slot went by
while a collection and the sonar's echo wait held the loop skips it (board/drivers, Periodic),
so which slots are skipped follows the collections; and where the firmware's own reading of its
lowest free (board/memory.py, LOW: gc.mem_free() before its collection) falls follows them
too.  Without any world, a heap 128 B larger is enough: 695 collections for 692, the compass's
shortest period 1054 µs for 1656 (a sample the sonar made late, the next on its instant: the
sonar's phase), the lowest free 43600 B for 62192.  That last is the start-up's: the host's
handshake and configuration allocate some 60 KiB between 0.52 and 0.62 s; at a Pico's heap the
allocator's own collection (gc.threshold reached) cuts that burst before the firmware's next
LOW, which then comes from later turns (62 to 66 KiB free), while 128 B more moved the
firmware's collections by a turn so that its LOW fell at the burst's end, before the
allocator's threshold was reached (the simulator's heap, collection by collection).
So the heap is held by what the collections see (the simulator's, fastclock.mjs "heap"): the
bytes live after each, past start-up, and the bytes allocated over the run; the timing by each
sensor's count, its periods that no collection overlaps, and for the aligned ones how late each
sample is against its host-time instant.  A world that kept 14 KiB in the board's heap by the
end, made 0.54 % more garbage there, or took 16 µs of the board's time at each step or 300 µs
at each of its ticks fails here (throwaway probes: docs/performance.md)."""

from __future__ import annotations

import ast
import bisect
import itertools
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from missing_link.daemon.session.board_memory import parse_memory
from missing_link.daemon.session.status import MemoryStatus
from missing_link.deploy.heap import FREE_HEAP
from missing_link.host.board import Board
from missing_link.transport import open_transport
from missing_link.virtual.world_mpy import NodeWorld
from missing_link.world.worldfile import parse

from .memory_soak import FastSim, SoakResult, soak

ROVER = Path(__file__).resolve().parent.parent / "examples" / "boards" / "rover.py"
AVR_ROVER = ROVER.with_name("rover-mega.py")
BOARD: dict[str, Any] = ast.literal_eval(ROVER.read_text().split("BOARD = ", 1)[1])
PICO = FREE_HEAP["rp2040"].bytes
SECONDS = 20
NEAR_WALL = "[start]\nx_m = 3.88\n"  # (its rangers' front edge 1 m from the wall ahead)
#: board µs of start-up: the host's handshake and configuration (the allocator collects there)
STARTUP_US = 1_000_000
LIVE_SLACK = 1024  # B: a few objects (measured: the world's run 304 B more at most)
ALLOCATED = 0.005  # of all the run allocated (measured: 0.16 % at most, 19 KB of 11.5 MB)
JITTER_US = 100  # (measured: 56 at most; a sample is 20 ms apart at the most)
LATE_US = 5  # (an aligned sample's lateness, median and tenth: measured the same to the µs)
LATE_TAIL_US = 50  # (... its ninetieth: measured 13 µs apart at most)
pytestmark = [pytest.mark.slow]


def _soaked(world: bool) -> tuple[SoakResult, dict[str, Any], NodeWorld | None]:
    beside = NodeWorld(parse(NEAR_WALL, "near-wall.toml"), BOARD, 0, frozenset()) if world else None
    sim = FastSim(ROVER, PICO, world=beside)
    try:
        res = soak(sim, SECONDS, ["compass", "wheel_l", "wheel_r"])
        gc = sim.figure("gc")
        assert sim.ctl("result = 1") == 1  # (the firmware still steps)
    finally:
        sim.close()
    return res, gc, beside


@pytest.fixture(scope="module")
def both() -> dict[bool, tuple[SoakResult, dict[str, Any], NodeWorld | None]]:
    return {world: _soaked(world) for world in (False, True)}


def _periods(stamps: list[int]) -> list[int]:
    return [b - a for a, b in itertools.pairwise(stamps)]


def _between_collections(stamps: list[int], log: list[list[Any]]) -> list[int]:
    """The periods between two samples that no collection overlaps (log: [from, to, kind] in
    board µs, in time order, as the samples' stamps are)."""
    starts = [span[0] for span in log]
    out = []
    for a, b in itertools.pairwise(stamps):
        i = bisect.bisect_left(starts, a)
        if (i < len(log) and log[i][0] < b) or (i > 0 and log[i - 1][1] > a):
            continue
        out.append(b - a)
    return out


@pytest.mark.micropython
def test_the_world_was_there_and_the_firmware_read_it(both: dict[bool, Any]) -> None:
    res, _gc, world = both[True]
    assert world is not None and world.link is not None and world.failed is None
    assert world.link.world.now_s() >= SECONDS  # (it ticked all along, in simulated time)
    assert res.valid["imu"] > 0 and res.valid["sonar"] > 0


def _heap(gc: dict[str, Any]) -> tuple[float, int, int]:
    """The collections' heap (fastclock.mjs "heap"): the median and the most bytes live after
    those past start-up, and the bytes allocated in the run (in use at each collection beyond
    what the one before left live)."""
    live = [h[1] for h, span in zip(gc["heap"], gc["log"], strict=True) if span[0] >= STARTUP_US]
    allocated = sum(b[0] - a[1] for a, b in itertools.pairwise(gc["heap"]))
    return statistics.median(live), max(live), allocated


@pytest.mark.micropython
def test_the_boards_heap_and_collections_are_the_same_with_its_world_and_without(
    both: dict[bool, Any],
) -> None:
    """The same live data after the collections within a few objects, the same bytes allocated
    within 0.5 %, each collection at the same cost within a few µs.  A world that held data in
    the board's heap would show in the live data, one that made garbage there in what was
    allocated.  Not held: the firmware's own lowest free (a2jMemory) and how many collections,
    which follow where the collections land (the module's docstring): 62192 and 43600 B, 692
    and 695 collections, without any world at a Pico's heap and 128 B more."""
    (without, gc0, _), (beside, gc1, _) = both[False], both[True]
    for m in (without.memory, beside.memory):
        assert m.problem == "" and m.heap_free_low is not None and m.heap_free_low > 0, m
    (median0, most0, alloc0), (median1, most1, alloc1) = _heap(gc0), _heap(gc1)
    assert abs(median1 - median0) <= LIVE_SLACK and abs(most1 - most0) <= LIVE_SLACK
    assert abs(alloc1 - alloc0) <= ALLOCATED * alloc0, (alloc0, alloc1)
    for figure in (min, statistics.median, max):  # (what each collection took, µs)
        assert abs(figure(gc1["us"]) - figure(gc0["us"])) <= 20
    assert min(without.board_us, beside.board_us) >= SECONDS * 1_000_000


def _lateness(stamps: list[int], period_us: int) -> tuple[int, int, int]:
    """How late an aligned transducer's samples are against their instants (whole multiples of
    its period in board µs: memory_soak.py's host map): the median, the tenth and ninetieth."""
    late = sorted(t % period_us for t in stamps)
    n = len(late)
    return late[n // 2], late[n // 10], late[n * 9 // 10]


@pytest.mark.micropython
@pytest.mark.parametrize("name", ["imu", "compass", "wheel_l", "sonar", "tof", "gps"])
def test_each_sensors_sample_timing_is_the_same_with_its_world_and_without(
    both: dict[bool, Any], name: str
) -> None:
    """As many samples within 1 % (a slot that went by while a collection and the sonar held the
    loop is skipped, as they land: the IMU's 993 to 998 of 1000 without any world at heaps from
    a Pico's to 256 B more), the shortest and longest periods that no collection overlaps within
    JITTER_US (where a world that took the board's time would show; the aligned ones' shortest
    not: it follows the sonar's phase, 1054 or 1656 µs as above), and the longest of all within
    one collection (6.8 ms: it lands in a period or the next).  An aligned sample's lateness
    against its host-time instant is what aligned sampling promises: its median and tenth
    within LATE_US, its ninetieth within LATE_TAIL_US.  The sonar, the ToF ranger and the GPS
    have no period without a collection (one every ~30 ms)."""
    (without, gc0, _), (beside, gc1, _) = both[False], both[True]
    p0, p1 = _periods(without.stamps[name]), _periods(beside.stamps[name])
    aligned = name in {"compass", "wheel_l"}
    assert len(p0) >= SECONDS - 2  # (the GPS: once a second)
    assert abs(len(p1) - len(p0)) <= max(1, len(p0) // 100)
    if not aligned:
        assert abs(min(p1) - min(p0)) <= JITTER_US
    assert abs(max(p1) - max(p0)) <= JITTER_US + max(gc0["us"] + gc1["us"])
    q0 = _between_collections(without.stamps[name], gc0["log"])
    q1 = _between_collections(beside.stamps[name], gc1["log"])
    assert bool(q0) == bool(q1) == (name in {"imu", "compass", "wheel_l"})
    if q0:
        assert abs(max(q1) - max(q0)) <= JITTER_US
        assert aligned or abs(min(q1) - min(q0)) <= JITTER_US
    if aligned:
        period = int(
            1_000_000 / next(t for t in BOARD["transducers"] if t["name"] == name)["rate_hz"]
        )
        (med0, tenth0, tail0), (med1, tenth1, tail1) = (
            _lateness(without.stamps[name], period),
            _lateness(beside.stamps[name], period),
        )
        assert abs(med1 - med0) <= LATE_US and abs(tenth1 - tenth0) <= LATE_US
        assert abs(tail1 - tail0) <= LATE_TAIL_US


def _avr_memory(world: Path | None) -> MemoryStatus:
    """The AVR rover (rover-mega.py in simavr, `board --file --runtime avr`) with ``world`` or
    none: its own memory figures (a2jMemory) after its handshake, configuration and 2 s of
    samples on its clock."""
    cmd = [sys.executable, "-m", "missing_link", "board", "--file", str(AVR_ROVER), "--runtime",
           "avr", "--listen", "tcp://127.0.0.1:0", "--world", str(world or "none")]  # fmt: skip
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        assert proc.stdout is not None
        url = proc.stdout.readline().split()[1]
        with Board(open_transport(url), timeout=5.0) as board:
            board.handshake()
            board.config()
            t0 = board.clock_exchange(5.0).t3
            while board.clock_exchange(5.0).t3 - t0 < 2_000_000:
                time.sleep(0.2)
            return parse_memory(board.call_ok("a2jMemory"))
    finally:
        proc.terminate()
        proc.wait(15)


@pytest.mark.avr
def test_the_avr_boards_memory_is_the_same_with_its_world_and_without(tmp_path: Path) -> None:
    """On AVR the world drives the rig's parts from outside the AVR (their control lines,
    world_avr.py): the firmware's static RAM and its stack's lowest free are the same."""
    near = tmp_path / "near-wall.toml"
    near.write_text(NEAR_WALL)
    without, beside = _avr_memory(None), _avr_memory(near)
    assert without.problem == beside.problem == ""
    assert beside.ram_static == without.ram_static and beside.ram_size == without.ram_size
    assert beside.stack_free_low == without.stack_free_low, (without, beside)
