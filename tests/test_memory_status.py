"""The board's memory in the host's status: a2jMemory read once per diagnostics period in the
background (daemon/session/board_memory.py), shown in ``status()``, ``/diagnostics`` and ``info
--json``; the board's own garbage collection kept off the instants it must be on time for
(board/memory.py) on CPython with a fake heap and clock, as the MicroPython firmware runs it."""

from __future__ import annotations

import json
import struct
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from rosbags.typesys import Stores, get_typestore

from missing_link.board.memory import MAX_PERIOD_US, MIN_PERIOD_US, PERIOD_US, Memory
from missing_link.board.runtime import BoardRuntime
from missing_link.board.timing import MARGIN_US, Timing
from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config
from missing_link.daemon.session.board_memory import parse_memory
from missing_link.ros.diagnostics import DIAG_TYPE, diagnostics_cdr

from .helpers import AvrSim, FirmwareSim, wait_for

ROOT = Path(__file__).resolve().parent.parent
RIG = ROOT / "examples" / "boards" / "thesis-rig.py"
HEAP_KEYS = ("heap_free", "heap_free_low", "heap_alloc", "gc_collections", "gc_longest_us",
             "gc_last_us", "gc_overlaps", "gc_deferred")  # fmt: skip
STACK_KEYS = ("stack_free_low", "stack_size", "ram_static", "ram_size")


# ---- the firmware's own collections (board/memory.py), on a fake heap and clock -------------
class FakeClock:
    def __init__(self) -> None:
        self.now = 0

    def __call__(self) -> int:
        return self.now


class FakeHeap:
    """MicroPython's gc as board/memory.py uses it: a collection takes ``took`` µs of the
    clock, a heap scan (mem_free, mem_alloc) ``scan`` µs; what it frees is what was allocated
    since the last."""

    def __init__(self, clock: FakeClock, took: int, scan: int = 0) -> None:
        self.clock, self.took, self.scan = clock, took, scan
        self.live, self.garbage, self.size = 60_000, 0, 200_000
        self.spans: list[tuple[int, int]] = []
        self.scans: list[tuple[int, int]] = []
        self.thresholds: list[int] = []

    def collect(self) -> None:
        start = self.clock.now
        self.clock.now += self.took
        self.garbage = 0
        self.spans.append((start, self.clock.now))

    def _scanned(self) -> None:
        self.scans.append((self.clock.now, self.clock.now + self.scan))
        self.clock.now += self.scan

    def mem_free(self) -> int:
        self._scanned()
        return self.size - self.live - self.garbage

    def mem_alloc(self) -> int:
        self._scanned()
        return self.live + self.garbage

    def threshold(self, n: int) -> None:
        self.thresholds.append(n)


class Aligned:
    """A driver sampling on the host-time grid (timing.next_instant reads these)."""

    def __init__(self, period_us: int) -> None:
        self.aligned, self.period_us, self.phase = True, period_us, 0.0

    def next_due_us(self) -> int | None:
        return None


def _board(
    took: int, period_us: int, scan: int = 0
) -> tuple[BoardRuntime, FakeClock, FakeHeap, Memory]:
    clock = FakeClock()
    rt = BoardRuntime("b", "m", "s", clock=clock, epoch="e")
    from missing_link.board.transducer import Transducer

    rt.add_transducer(Transducer("imu", 0, "p", "m", 1, "int16_t", -1), Aligned(period_us))
    rt.timing = Timing(rt)
    rt.host_map = (0, 0, 0)  # board µs = host ns / 1000: the grid is whole periods of board µs
    heap = FakeHeap(clock, took, scan)
    return rt, clock, heap, Memory(rt, heap)


def test_the_firmware_collects_only_with_room_before_the_next_instant() -> None:
    """A 10 ms grid and collections of 3 ms: over ten simulated seconds of loop turns every
    200 µs, collections happen (about every PERIOD_US), none holds up an instant, and those
    put off for one are counted."""
    rt, clock, heap, mem = _board(took=3000, period_us=10_000)
    while clock.now < 10_000_000:
        rt.host_map = (clock.now, clock.now * 1000, 0)  # (fresh: the map stays valid)
        heap.garbage += 800
        mem.poll(clock.now)
        clock.now += 200
    spans = heap.spans[1:]  # (the first is at boot, before any grid)
    assert len(spans) >= 10_000_000 // PERIOD_US * 0.9
    # (an instant at a span's start was measured before it, in that turn: no instant in (a, b])
    assert all(b // 10_000 == a // 10_000 for a, b in spans), spans[:5]
    assert mem.overlaps == 0 and mem.deferred > 0
    assert mem.longest_us == 3000 and mem.collections == len(heap.spans)
    assert heap.thresholds and min(heap.thresholds) >= 4096
    assert mem.free_low is not None and mem.free_low < mem.free


def test_a_heap_scan_takes_its_own_room_apart_from_the_collection() -> None:
    """A Pico's heap scans take milliseconds too (gc.mem_free walks the whole allocation
    table): on a 10 ms grid a scan of 4.5 ms and a collection of 4.5 ms never fit in one
    window, so each goes in a window of its own, the low point just before the collection and
    the figures after it at later turns, and no span of either holds an instant."""
    rt, clock, heap, mem = _board(took=4500, period_us=10_000, scan=4500)
    while clock.now < 5_000_000:
        rt.host_map = (clock.now, clock.now * 1000, 0)
        heap.garbage += 800
        mem.poll(clock.now)
        clock.now += 1000  # (a turn a ms after the last)
    spans, scans = heap.spans[1:], heap.scans[2:]  # (the firmware's, after boot)
    assert len(spans) >= 5_000_000 // PERIOD_US * 0.8
    # the low point before each collection and the free bytes after it; the allocated bytes
    # after one a second (FIGURES_US)
    assert 2 * len(spans) + 4 <= len(scans) <= 2 * len(spans) + 6, (len(spans), len(scans))
    for a, b in spans + scans:
        assert b // 10_000 == a // 10_000, (a, b)  # (no instant in (a, b])
    windows = {a // 10_000 for a, _ in spans}
    assert not windows & {a // 10_000 for a, _ in scans}  # never in one window together
    assert mem.overlaps == 0 and mem.scan_us == 4500 and mem.longest_us == 4500


def test_a_late_reading_of_the_free_heap_does_not_lower_the_threshold() -> None:
    """The allocator counts from the collection: a reading of the free bytes made turns after
    it (no room for the scan sooner) has their garbage in it, 20 kB here, and the threshold
    stays 3/4 of the most free read lately (less 1/32 a reading, to follow live data that
    grew), not of the late reading."""
    _rt, clock, heap, mem = _board(took=1000, period_us=1_000_000)
    late = None
    while clock.now < 3_000_000:
        n = len(heap.spans)
        mem.poll(clock.now)
        clock.now += 1000
        heap.garbage += 800
        if len(heap.spans) == 10 and n == 9:  # (the turn after the tenth collection)
            heap.garbage += 20_000
            late = len(heap.thresholds)
    assert late is not None and len(heap.thresholds) > late + 5
    best = heap.size - heap.live - 800  # (a reading at the next turn: one turn's garbage)
    assert heap.thresholds[late - 1] == best * 3 // 4
    assert heap.thresholds[late] == (best - best // 32) * 3 // 4  # not (best - 20 kB) * 3/4
    assert heap.thresholds[late + 1] == best * 3 // 4


def test_the_collection_period_follows_the_allocation_rate() -> None:
    """A stepper's float maths (4 MB/s of garbage) brings the period down to MIN_PERIOD_US; a
    quiet board (10 kB/s) up to MAX_PERIOD_US; more free now than after the last collection
    (the allocator collected meanwhile) halves it."""
    for per_turn, period in ((800, MIN_PERIOD_US), (2, MAX_PERIOD_US)):
        rt, clock, heap, mem = _board(took=500, period_us=1_000_000)
        while clock.now < 5_000_000:
            rt.host_map = (clock.now, clock.now * 1000, 0)
            heap.garbage += per_turn
            mem.poll(clock.now)
            clock.now += 200
        assert mem.period_us == period, (per_turn, mem.period_us)
    before, done = mem.period_us, mem.collections
    heap.garbage, heap.live = 0, heap.live - 1000  # (less in use than after the last one)
    while mem.collections == done:  # (the next collection, when the grid leaves room)
        rt.host_map = (clock.now, clock.now * 1000, 0)
        mem.poll(clock.now)
        clock.now += 200
    assert mem.period_us == before // 2


def test_a_collection_that_takes_longer_than_the_room_is_counted_not_hidden() -> None:
    """The first collection after boot is timed 3 ms; the next one takes 9 ms where 3 + 1 ms
    of margin looked enough: it reaches the instant, and a2jMemory says so."""
    rt, clock, heap, mem = _board(took=3000, period_us=10_000)
    heap.took = 9000
    clock.now = 3 * PERIOD_US + 10_000 - (3000 + MARGIN_US + 500)  # room for 3 ms + margin
    rt.host_map = (clock.now, clock.now * 1000, 0)
    mem.poll(clock.now)
    assert mem.overlaps == 1 and mem.last_us == 9000 and mem.longest_us == 9000
    got = parse_memory(mem._info(b"")[1])
    assert got.gc_overlaps == 1 and got.gc_longest_us == 9000


def test_parse_memory_says_what_is_wrong_with_a_reply() -> None:
    assert parse_memory(b"").problem.startswith("a reply of kind None")
    assert parse_memory(b"\x07" + bytes(8)).problem.startswith("a reply of kind 7")
    assert "not 33" in parse_memory(b"\x01" + bytes(8)).problem
    ok = parse_memory(struct.pack("<BHHHH", 2, 166, 436, 1612, 2048))
    assert (ok.stack_free_low, ok.stack_size, ok.ram_static, ok.ram_size) == (166, 436, 1612, 2048)


# ---- the host's side ---------------------------------------------------------------------
@pytest.fixture(scope="module")
def sim() -> Iterator[FirmwareSim]:
    s = FirmwareSim(RIG)
    try:
        yield s
    finally:
        s.close()


def _diagnostics_values(status: list[dict[str, object]]) -> dict[str, str]:
    store = get_typestore(Stores.ROS2_JAZZY)
    msg = store.deserialize_cdr(diagnostics_cdr(store, status, time.time_ns()), DIAG_TYPE)
    return {kv.key: kv.value for kv in msg.status[0].values}


@pytest.mark.micropython
@pytest.mark.slow
def test_status_and_diagnostics_show_the_micropython_boards_heap(sim: FirmwareSim) -> None:
    with Daemon(Config(boards=[BoardSpec(sim.url, timeout=2.0)], diagnostics_period=0.2)) as d:
        assert d.wait_until_up(30), d.failures()
        assert wait_for(lambda: "heap_free" in d.status()[0], 20), d.status()[0]
        status = d.status()
    s = status[0]
    assert set(HEAP_KEYS) <= set(s) and not set(STACK_KEYS) & set(s)
    assert 0 < s["heap_free_low"] <= s["heap_free"] and s["heap_alloc"] > 0
    assert s["gc_collections"] >= 1 and s["gc_overlaps"] == 0
    values = _diagnostics_values(status)
    assert values["heap_free"] == str(s["heap_free"]) and "gc_longest_us" in values


@pytest.mark.micropython
@pytest.mark.slow
def test_info_json_shows_the_boards_memory(sim: FirmwareSim) -> None:
    r = subprocess.run(
        [sys.executable, "-m", "missing_link", "info", sim.url, "--json"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    memory = json.loads(r.stdout)["memory"]
    assert set(HEAP_KEYS) <= set(memory) and memory["heap_free"] > 0


@pytest.mark.avr
@pytest.mark.slow
def test_status_shows_the_avr_boards_stack_low_point(avr_build: Path) -> None:
    rig = AvrSim(avr_build, avr_build / "uno_rig" / "firmware.elf")
    try:
        spec = BoardSpec(rig.url, timeout=2.0)
        with Daemon(Config(boards=[spec], diagnostics_period=0.2)) as d:
            assert d.wait_until_up(30), d.failures()
            assert wait_for(lambda: "stack_free_low" in d.status()[0], 20), d.status()[0]
            s = d.status()[0]
    finally:
        rig.close()
    assert set(STACK_KEYS) <= set(s) and not set(HEAP_KEYS) & set(s)
    assert 64 <= s["stack_free_low"] < s["stack_size"] and s["ram_size"] == 2048
