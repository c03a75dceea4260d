"""The world beside the firmware, not in it (issue 47.6): the rover's MicroPython firmware in a
Raspberry Pi Pico's heap, in simulated time and in lockstep with its host (memory_soak.py:
host.mjs --heap --fast --lockstep), served the same way with its world beside it and with
none, holds the same live data, allocates the same, keeps each sensor on its schedule the same
way and its clock the same.

The world runs in this process (world_mpy.py) and reaches the firmware's devices between its
steps with small integers only; the simulated clock moves on by what the firmware's own work
costs (simcost.py), never by the world's.  The world puts the rover 1 m before a wall, where
the simulator's parts put their target without a world (pin_devices.py, i2c_devices.py), so
the firmware does the same work in both: what differs is only what its sensors read.  Same
host, same commands, same simulated seconds: the figures are statements about the firmware, on
a quiet machine or a busy one, and each run is the same every time.

Which figures: the run is chaotic in where things land.  A few allocations more or less (what
the firmware makes of what it reads: a fix's digits) move a collection by a loop turn, and with
it where the sonar's rangings (its echo wait holds the loop some 6 ms) fall against the other
slots; a periodic driver whose slot went by while they held the loop skips it (board/drivers,
Periodic).  So any change of the firmware's cost (one clock read less) re-deals which samples
are held and by how much: a figure that follows one such landing - a slot's longest or
shortest period, a period between two given collections, the collections' count, the
firmware's own lowest free (LOW: one reading, before one collection) - flips with the firmware
and is not held here.  Without any world, a heap 128 B larger gives 707 collections for 698,
the compass's longest period 39.7 ms for 24.8 (a skipped slot) and the lowest free 48.5 KB for
58.7; a cost-only cut of board/pacing.py moved the compass's longest period 6.5 ms apart with
and without the world, the sonar's and a wheel's 14.9 ms.  What is held is what the world cannot
change without being in the firmware, and what a world that was in it would break:
* the heap, by what the collections see (the simulator's, fastclock.mjs "heap"): the bytes live
  after each past start-up (median and most) and the bytes allocated over the run, and what
  each collection took;
* each sensor's timing by its own schedule, as a distribution over the run: its count and mean
  period, how many periods are early, on time (within ON_TIME_US of the period) and late (a
  band, BAND, wide enough for the landings: 7 of 1000 at most measured); no period longer than
  two periods and HOLD_US in either run; for the aligned ones how late each sample is against
  its host-time instant (median, tenth and ninetieth: the same to a few µs);
* the clock: the board's against its host's (the simulation's) at each clock exchange, the
  same within a few µs.
A world that hands the board's heap 64 B of garbage at each IMU feed (its feed's objects in the
board's heap), or that holds the firmware 300 µs at each IMU read (its hand in a part charged to
the board's time), fails here: test_a_world_in_the_firmware_fails_here injects both.  What the
bands cannot see (one float a feed: 0.38 % more allocated) the heap allocated where the world
runs, between the firmware's steps, holds: 0 B (FEED_HEAP, world_beside_sim.py), at rest and
driven (the host commands the motors: the world's edges, its batches cut and gone back over),
where the board's clock is held the same as without a world driven the same way."""

from __future__ import annotations

import itertools
import statistics
import struct
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from missing_link.daemon.session.board_memory import parse_memory
from missing_link.daemon.session.status import MemoryStatus
from missing_link.deploy.boardfile import load_board_file
from missing_link.deploy.heap import FREE_HEAP
from missing_link.host.board import Board
from missing_link.transport import open_transport
from missing_link.virtual.world_mpy import NodeWorld
from missing_link.world.worldfile import parse

from .memory_soak import TURN_US, FastSim, SoakResult, soak
from .world_beside_sim import DUTIES, EDGE, FEED_HEAP, FLOAT, GARBAGE, HOLD

ROVER = Path(__file__).resolve().parent.parent / "examples" / "boards" / "rover.py"
AVR_ROVER = ROVER.with_name("rover-mega.py")
BOARD: dict[str, Any] = load_board_file(ROVER).board
PICO = FREE_HEAP["rp2040"].bytes
SECONDS = 20
ALIGNED = ("compass", "wheel_l", "wheel_r")
NEAR_WALL = "[start]\nx_m = 3.88\n"  # (its rangers' front edge 1 m from the wall ahead)
#: board µs of start-up: the host's handshake and configuration (the allocator collects there)
STARTUP_US = 1_000_000
LIVE_SLACK = 1024  # B: a few objects (measured: the world's run 304 B more at most)
ALLOCATED = 0.005  # of all the run allocated (measured: 0.16 % at most, 19 KB of 11.5 MB)
COLLECTION_US = 20  # what a collection took, its shortest, median and longest
MEAN = 0.005  # a sensor's mean period (measured: 0.2 % apart at most, a skipped slot or two)
ON_TIME_US = 1000  # a period within a ms of the schedule's is on time
BAND = 0.02  # of a sensor's periods, and at least BAND_LEAST, each band's count (early, ...)
BAND_LEAST = 5
HOLD_US = 20_000  # beyond two periods: a collection (6.8 ms) and a ranging's echo wait
LATE_US = 5  # (an aligned sample's lateness, median and tenth: measured the same to the µs)
LATE_TAIL_US = 50  # (... its ninetieth: measured 13 µs apart at most)
OFFSET_US = 20  # the board clock less the host's at the exchanges, least, median and most
pytestmark = [pytest.mark.slow]


@dataclass
class Run:
    res: SoakResult
    gc: dict[str, Any]  #: the simulator's collections (FastSim.figure("gc"))
    offsets: list[int]  #: the board clock less the host's at each clock exchange (t2 - t1), µs
    world: NodeWorld | None
    #: FEED_HEAP's figures: [bytes allocated between steps without the host's bytes, those
    #: steps, the most in one, bytes allocated between steps with the host's bytes, those steps]
    feed_heap: list[int]


def _soaked(
    world: bool, fault: str | None = None, driven: bool = False, probe: bool = False
) -> Run:
    """``probe``: FEED_HEAP counts the heap where the world runs (its own objects in the heap
    move where the collections land, as any change: the runs compared are both probed or not)."""
    beside = NodeWorld(parse(NEAR_WALL, "near-wall.toml"), BOARD, 0, frozenset()) if world else None
    sim = FastSim(ROVER, PICO, world=beside)

    offsets: list[int] = []
    turns = SECONDS * 1_000_000 // TURN_US

    def inject(board: Board, turn: int) -> int:
        if turn == 0:
            if probe:
                sim.ctl(FEED_HEAP)
            exchange = board.clock_exchange

            def noted(timeout: float | None = None, **kw: Any) -> Any:
                x = exchange(timeout, **kw)
                offsets.append(x.t2 - x.t1 // 1000)
                return x

            board.clock_exchange = noted  # type: ignore[method-assign]
            if fault is not None:  # (the world attached its parts at the first step)
                sim.ctl(fault)
        if not driven:
            return 0
        duty = struct.pack("<f", DUTIES[turn * 2 >= turns])
        for side in ("l", "r"):
            board.call_ok(f"a2j_motor_{side}", duty)
        return 2

    try:
        res = soak(sim, SECONDS, ALIGNED, act=inject)
        gc = sim.figure("gc")
        read = "import simworld.mpyhost as H\nresult = H.FEED_HEAP[3:]"
        feed_heap = sim.ctl(read) if probe else []
        assert sim.ctl("result = 1") == 1  # (the firmware still steps)
    finally:
        sim.close()
    return Run(res, gc, offsets, beside, feed_heap)


@pytest.fixture(scope="module")
def both() -> dict[bool, Run]:
    return {world: _soaked(world) for world in (False, True)}


@pytest.mark.micropython
def test_the_world_was_there_and_the_firmware_read_it(both: dict[bool, Run]) -> None:
    run = both[True]
    world = run.world
    assert world is not None and world.link is not None and world.failed is None
    assert world.link.world.now_s() >= SECONDS  # (it ticked all along, in simulated time)
    assert run.res.valid["imu"] > 0 and run.res.valid["sonar"] > 0
    for r in both.values():
        assert r.res.memory.problem == "" and r.res.board_us >= SECONDS * 1_000_000


def _heap(gc: dict[str, Any]) -> tuple[float, int, int]:
    """The collections' heap (fastclock.mjs "heap"): the median and the most bytes live after
    those past start-up, and the bytes allocated in the run (in use at each collection beyond
    what the one before left live)."""
    live = [h[1] for h, span in zip(gc["heap"], gc["log"], strict=True) if span[0] >= STARTUP_US]
    allocated = sum(b[0] - a[1] for a, b in itertools.pairwise(gc["heap"]))
    return statistics.median(live), max(live), allocated


def heap_differences(a: Run, b: Run) -> list[str]:
    """What differs in the heap beyond a few objects: the live data after the collections,
    what was allocated (ALLOCATED), what each collection took (COLLECTION_US)."""
    out = []
    (median0, most0, alloc0), (median1, most1, alloc1) = _heap(a.gc), _heap(b.gc)
    if abs(median1 - median0) > LIVE_SLACK or abs(most1 - most0) > LIVE_SLACK:
        out.append(f"live after collections {median0}, {most0} B against {median1}, {most1}")
    if abs(alloc1 - alloc0) > ALLOCATED * alloc0:
        out.append(f"allocated {alloc0} B against {alloc1}")
    for figure in (min, statistics.median, max):
        if abs(figure(b.gc["us"]) - figure(a.gc["us"])) > COLLECTION_US:
            out.append(f"a collection's {figure.__name__} {figure(a.gc['us'])} µs against "
                       f"{figure(b.gc['us'])}")  # fmt: skip
    return out


def _period_us(name: str) -> int:
    rate = next(t for t in BOARD["transducers"] if t["name"] == name).get("rate_hz", 1)
    return int(1_000_000 / rate)


def _schedule(stamps: list[int], period: int) -> tuple[int, float, int, int, int]:
    """A sensor's samples by its schedule: how many, the mean period, and how many periods are
    early, on time (within ON_TIME_US) and late."""
    p = [b - a for a, b in itertools.pairwise(stamps)]
    early = sum(x < period - ON_TIME_US for x in p)
    late = sum(x > period + ON_TIME_US for x in p)
    return len(stamps), (stamps[-1] - stamps[0]) / len(p), early, len(p) - early - late, late


def _lateness(stamps: list[int], period_us: int) -> tuple[int, int, int]:
    """How late an aligned transducer's samples are against their instants (whole multiples of
    its period in board µs: memory_soak.py's host map): the median, the tenth and ninetieth."""
    late = sorted(t % period_us for t in stamps)
    n = len(late)
    return late[n // 2], late[n // 10], late[n * 9 // 10]


def timing_differences(name: str, a: Run, b: Run) -> list[str]:
    """What differs in sensor ``name``'s timing beyond where the landings fall (the module's
    docstring), and any period longer than two and HOLD_US in either run."""
    period = _period_us(name)
    s0, s1 = (_schedule(r.res.stamps[name], period) for r in (a, b))
    out = []
    if abs(s1[0] - s0[0]) > max(1, s0[0] // 100) or abs(s1[1] - s0[1]) > MEAN * period:
        out.append(f"{name}: {s0[0]} samples {s0[1]:.0f} µs apart against {s1[0]}, {s1[1]:.0f}")
    band = max(BAND_LEAST, int(BAND * s0[0]))
    if any(abs(x1 - x0) > band for x0, x1 in zip(s0[2:], s1[2:], strict=True)):
        out.append(f"{name}: early, on time, late {s0[2:]} against {s1[2:]}")
    for r in (a, b):
        longest = max(y - x for x, y in itertools.pairwise(r.res.stamps[name]))
        if longest > 2 * period + HOLD_US:
            out.append(f"{name}: a period of {longest} µs")
    if name in ALIGNED:
        (med0, tenth0, tail0), (med1, tenth1, tail1) = (
            _lateness(r.res.stamps[name], period) for r in (a, b)
        )
        if abs(med1 - med0) > LATE_US or abs(tenth1 - tenth0) > LATE_US:
            out.append(f"{name}: late by {med0}, {tenth0} µs against {med1}, {tenth1}")
        if abs(tail1 - tail0) > LATE_TAIL_US:
            out.append(f"{name}: late by {tail0} µs at the ninetieth against {tail1}")
    return out


SENSORS = ["imu", "compass", "wheel_l", "wheel_r", "sonar", "tof", "gps"]


@pytest.mark.micropython
def test_the_boards_heap_and_collections_are_the_same_with_its_world_and_without(
    both: dict[bool, Run],
) -> None:
    """The same live data after the collections within a few objects, the same bytes allocated
    within 0.5 %, each collection at the same cost within a few µs.  A world that held data in
    the board's heap would show in the live data, one that made garbage there in what was
    allocated."""
    assert heap_differences(both[False], both[True]) == []


@pytest.mark.micropython
@pytest.mark.parametrize("name", SENSORS)
def test_each_sensors_sample_timing_is_the_same_with_its_world_and_without(
    both: dict[bool, Run], name: str
) -> None:
    """As many samples within 1 %, the same mean period within 0.5 %, as many early, on time and
    late within BAND (where a world that took the board's time would show: its slots held
    more often), none held past two periods and HOLD_US, and an aligned sample's lateness
    against its host-time instant - what aligned sampling promises - the same: its median and
    tenth within LATE_US, its ninetieth within LATE_TAIL_US."""
    assert len(both[False].res.stamps[name]) >= SECONDS - 2  # (the GPS: once a second)
    assert timing_differences(name, both[False], both[True]) == []


def clock_differences(a: Run, b: Run) -> list[str]:
    """What differs in the board's clock against its host's (the simulation's: memory_soak.py's
    lockstep host) at the host's clock exchanges, one a TURN_US or so: the board's stamp as the
    request came in (a2jClock's t2) less the host's as it sent it (t1), its least, median and
    most within OFFSET_US (measured: 7 µs apart at most, the same on every run; t4 is not
    used: the host's reader stamps it as its thread gets there, a quantum late or not)."""
    out = []
    for figure in (min, statistics.median, max):
        x0, x1 = figure(a.offsets), figure(b.offsets)
        if abs(x1 - x0) > OFFSET_US:
            out.append(f"the board clock less the host's, {figure.__name__} {x0} µs against {x1}")
    return out


@pytest.mark.micropython
def test_the_boards_clock_is_the_same_with_its_world_and_without(both: dict[bool, Run]) -> None:
    """The board clock keeps the simulation's as its host sees it in the clock exchanges: a
    world that held or moved it (an edge's time is the board clock's while its handler runs:
    worldfeed.steps_at) would not."""
    assert len(both[False].offsets) >= SECONDS * 1_000_000 // TURN_US // 2
    assert clock_differences(both[False], both[True]) == []


@pytest.mark.micropython
@pytest.mark.parametrize("fault", ["GARBAGE", "HOLD"])
def test_a_world_in_the_firmware_fails_here(both: dict[bool, Run], fault: str) -> None:
    """The figures above catch a world that is in the firmware: one that leaves garbage in the
    board's heap at each IMU feed (GARBAGE: 0.9 % more allocated), or holds the firmware 300 µs
    at each IMU read (HOLD)."""
    faulty = _soaked(True, {"GARBAGE": GARBAGE, "HOLD": HOLD}[fault])
    found = (
        heap_differences(both[False], faulty)
        + clock_differences(both[False], faulty)
        + [d for name in SENSORS for d in timing_differences(name, both[False], faulty)]
    )
    assert found, fault
    # (each where it should show: the garbage in what was allocated, the hold in the IMU's
    # periods; the others may follow, as where the collections land moves)
    assert any(d.startswith("allocated" if fault == "GARBAGE" else "imu: early") for d in found)


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


def feed_heap_differences(run: Run) -> list[str]:
    """What the heap took between the firmware's steps, where the world's feed calls and edges
    run (FEED_HEAP): nothing, in the steps that took none of the host's bytes (most of them)."""
    clean, steps, most, _hosts, host_steps = run.feed_heap
    if steps < 2 * host_steps:
        return [f"{steps} steps measured, {host_steps} with the host's bytes"]
    return [f"{clean} B allocated between the steps, {most} B at most"] if clean else []


@pytest.mark.micropython
@pytest.mark.parametrize("world", [False, True])
def test_the_worlds_feed_calls_allocate_nothing_in_the_boards_heap(
    driven: dict[bool, Run], world: bool
) -> None:
    """The world's hands are small integers only: what its feed calls leave in the board's heap
    is 0 B, counted where they run (FEED_HEAP), at rest, as without a world (driven, where
    nothing runs there: the count itself leaves nothing).  The heap's figures above hold a few
    objects' and 0.5 % of the run's allocation, and would not see one float a feed (FLOAT:
    test_a_world_that_allocates_where_it_runs_fails_here)."""
    run = _soaked(True, probe=True) if world else driven[False]  # (no world: nothing runs there)
    assert feed_heap_differences(run) == []


@pytest.fixture(scope="module")
def driven() -> dict[bool, Run]:
    return {world: _soaked(world, driven=True, probe=True) for world in (False, True)}


@pytest.mark.micropython
def test_a_driven_world_leaves_the_boards_heap_and_clock_as_without_it(
    driven: dict[bool, Run],
) -> None:
    """Driven (DUTIES: the host commands the motors, and changes them mid-run) the world
    delivers the wheels' edges with the board's clock held at each (worldfeed.steps_at), cuts
    and goes back over its batches as the drives change: the heap allocated where it runs is 0
    B and the board keeps its clock, as without a world driven the same way.  The sensors'
    timing is not compared here: the firmware's own handlers for the edges (some 2,000 a
    second at 4.5 rad/s, 1440 counts a turn) take the board's time as a board's interrupts
    do, and without a world there are none (measured: the IMU 865 samples in 20 s against 995,
    the compass 950 against 1002, the GPS 20 and 20)."""
    run = driven[True]
    assert run.world is not None and run.world.failed is None and run.world.link is not None
    state = run.world.link.state()
    assert min(abs(w) for w in state["wheels_rad"]) > 1, state  # (the wheels turned)
    assert state["rewound"] > 0, state  # (a batch gone back over: the drives changed)
    assert min(run.res.commands, driven[False].res.commands) >= SECONDS * 1_000_000 // TURN_US
    assert feed_heap_differences(run) + clock_differences(driven[False], run) == []


@pytest.mark.micropython
@pytest.mark.parametrize("fault", ["FLOAT", "EDGE"])
def test_a_world_that_allocates_where_it_runs_fails_here(fault: str) -> None:
    """One float left at each IMU feed (FLOAT: within the heap figures' bands), or 16 B at each
    edge's handler (EDGE, driven): the heap allocated where the world runs is not 0."""
    faulty = _soaked(True, {"FLOAT": FLOAT, "EDGE": EDGE}[fault], fault == "EDGE", probe=True)
    assert feed_heap_differences(faulty) != []
