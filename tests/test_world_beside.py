"""The world beside the firmware, not in it (issue 47.6): the rover's MicroPython firmware in a
Raspberry Pi Pico's heap, in simulated time and in lockstep with its host (memory_soak.py:
host.mjs --heap --fast --lockstep), served the same way with its world beside it and with
none, shows the same heap, the same collections (within one: they follow the firmware's
allocation) and the same sample timing (outside collections; a collection moved is one more
or less in a sample's period).

The world runs in this process (world_mpy.py) and reaches the firmware's devices between its
steps with small integers only; the simulated clock moves on by what the firmware's own work
costs (simcost.py), never by the world's.  The world puts the rover 1 m before a wall, where
the simulator's parts put their target without a world (pin_devices.py, i2c_devices.py), so
the firmware does the same work in both: what differs is only what its sensors read.  Same
host, same commands, same simulated seconds: the figures are statements about the firmware, on
a quiet machine or a busy one."""

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
HEAP_SLACK = 1024  # B: a few allocations (measured: 16)
JITTER_US = 100  # (measured: 7 at most; a sample is 20 ms apart at the most)
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


@pytest.mark.micropython
def test_the_boards_heap_and_collections_are_the_same_with_its_world_and_without(
    both: dict[bool, Any],
) -> None:
    """The same collections within one, each at the same cost within a few µs, the heap's
    lowest within a few allocations (what the firmware makes of what it reads: a fix's digits, a
    number's size) and the same simulated seconds: the world took no simulated time of the
    board's.  Within one, not equal: the firmware collects on a period that follows its
    allocation rate (board/memory.py), so a few allocations more or less move its collections by
    a turn and can fit one more or one fewer into the run.  That is the firmware's behaviour,
    not the world's: without any world, a heap 128 B larger (PICO + 128) gives 690 collections
    for 691 (the simulator's clock is a function of the simulation: the same run every time)."""
    (without, gc0, _), (beside, gc1, _) = both[False], both[True]
    m0, m1 = without.memory, beside.memory
    assert abs(m1.gc_collections - m0.gc_collections) <= 1
    assert gc1["collections"]["auto"] == gc0["collections"]["auto"]  # (the allocator's own)
    assert abs(gc1["collections"]["req"] - gc0["collections"]["req"]) <= 1
    assert m0.heap_free_low is not None and m1.heap_free_low is not None
    assert abs(m1.heap_free_low - m0.heap_free_low) <= HEAP_SLACK, (m0, m1)
    for figure in (min, statistics.median, max):  # (what each collection took, µs)
        assert abs(figure(gc1["us"]) - figure(gc0["us"])) <= 20
    assert beside.board_us // 1000 == without.board_us // 1000


@pytest.mark.micropython
@pytest.mark.parametrize("name", ["imu", "compass", "wheel_l", "sonar", "tof", "gps"])
def test_each_sensors_sample_timing_is_the_same_with_its_world_and_without(
    both: dict[bool, Any], name: str
) -> None:
    """Every sample in its place: as many, the same mean period, the shortest within JITTER_US
    (each step's cost is its work's, and that work reads other numbers), and the periods that
    no collection overlaps the same within JITTER_US at both ends: there a world that took the
    board's time would show.  The longest of all periods within one collection of each other:
    a collection (6.8 ms) lands in a sample's period or the next as the collections move (the
    test above), the firmware's timing with a few allocations more or less, not the world's
    (without any world, a heap 128 B larger moves the IMU's longest by 3.4 ms and its longest
    outside collections by 15 µs).  The sonar, the ToF ranger and the GPS have no period
    without a collection (one every ~30 ms)."""
    (without, gc0, _), (beside, gc1, _) = both[False], both[True]
    p0, p1 = _periods(without.stamps[name]), _periods(beside.stamps[name])
    assert len(p1) == len(p0) >= SECONDS - 2  # (the GPS: once a second)
    assert statistics.mean(p1) == pytest.approx(statistics.mean(p0), abs=JITTER_US / 10)
    assert abs(min(p1) - min(p0)) <= JITTER_US
    assert abs(max(p1) - max(p0)) <= JITTER_US + max(gc0["us"] + gc1["us"])
    q0 = _between_collections(without.stamps[name], gc0["log"])
    q1 = _between_collections(beside.stamps[name], gc1["log"])
    assert bool(q0) == bool(q1) == (name in {"imu", "compass", "wheel_l"})
    if q0:
        assert abs(max(q1) - max(q0)) <= JITTER_US and abs(min(q1) - min(q0)) <= JITTER_US


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
