"""Memory on the real parts (issue 36, item 4): the MicroPython firmware of the rover and the
thesis rig runs ten simulated minutes in the heap a Raspberry Pi Pico has free after MicroPython
boots, its garbage collections never on an instant it must be on time for; the board says its
heap's figures (a2jMemory) and the daemon and ``info --json`` show them.

The firmware runs in the real MicroPython interpreter (WebAssembly port) with the simulator's
``--heap`` (a board's fixed heap: heap.mjs), ``--fast`` (simulated time: fastclock.mjs, what the
work costs on a Pico: simcost.py) and ``--lockstep`` (lockstep.mjs), served by a host that
decodes every SIF (memory_soak.py): the same run, collection for collection, on any machine, so
the checks are statements about the firmware, not about how busy the machine was."""

from __future__ import annotations

import json
import struct
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor, wait
from pathlib import Path
from typing import Any

import pytest

from missing_link.board.timing import MAP_LIFE_US
from missing_link.deploy.heap import FREE_HEAP
from missing_link.host.board import Board
from missing_link.transport import open_transport

from .helpers import wait_for
from .memory_soak import TURN_US, FastSim, SoakResult, grid_hits, soak, wait_turn

ROOT = Path(__file__).resolve().parent.parent
BOARDS = ROOT / "examples" / "boards"
PICO = FREE_HEAP["rp2040"].bytes
MINUTES = 10
#: board µs of start-up, where the allocator may collect on its own (measured: its last one at
#: 0.52 s, in the handshake; none later in ten minutes of either board)
STARTUP_US = 5_000_000
pytestmark = [pytest.mark.micropython, pytest.mark.slow]


def _rover_commands(board: Board, turn: int) -> int:
    """The rover's host: the motors back and forth, the mast round, the wheels turning."""
    if turn % 20:
        return 0
    speed = struct.pack("<f", 0.6 if turn % 40 else -0.6)
    board.call_ok("a2j_motor_l", speed)
    board.call_ok("a2j_motor_r", speed)
    board.call_ok("a2j_mast", struct.pack("<f", (turn // 20) % 4 * 0.25))
    return 3


def _rig_commands(board: Board, turn: int) -> int:
    """The rig's host: the servo swept, the camera triggered at a host time (a timed call)."""
    if turn % 20:
        return 0
    board.call_ok("a2j_set_servo", struct.pack("<b", (turn // 20) % 200 - 100))
    now = board.clock_exchange(30).t3  # (a second ahead: the board may run LEAD_MS ahead)
    at = struct.pack("<qB", (now + 1_000_000) * 1000, board.index["a2j_trigger"])
    board.call_ok("a2jAt", at + struct.pack("<H", 100))
    return 2


def _turn_wheels(sim: FastSim, pins: list[tuple[int, int]]) -> Callable[[Board, int], int]:
    def act(board: Board, turn: int) -> int:
        if turn % 50 == 0:
            for a, b in pins:
                sim.ctl(f"WORLD.encoder_steps({a}, {b}, {turn % 37 + 1})")
        return 0

    return act


Soaked = tuple[SoakResult, dict[str, Any], FastSim]


def _soaked(
    board_file: str,
    aligned: list[str],
    commands: Callable[[Board, int], int],
    wheels: list[tuple[int, int]],
) -> Soaked:
    sim = FastSim(BOARDS / board_file, PICO)
    try:
        turn_wheels = _turn_wheels(sim, wheels)
        res = soak(sim, MINUTES * 60, aligned, lambda b, t: commands(b, t) + turn_wheels(b, t))
        gc = sim.figure("gc")
        assert sim.ctl("result = 1") == 1  # (the firmware still steps: no CRASH, no BREAK)
    finally:
        sim.close()
    return res, gc, sim


def _check_soak(res: SoakResult, sim: FastSim, rates: dict[str, float]) -> None:
    err = "".join(sim.stderr)
    assert "MemoryError" not in err and "crashed" not in err, err[-2000:]
    assert "memory" not in res.debug.lower(), res.debug
    seconds = res.board_us / 1e6
    assert seconds >= MINUTES * 60
    for name, rate in rates.items():  # every sensor sampled at its rate, with values
        assert res.valid[name] >= 0.95 * rate * seconds, (name, res.valid[name], rate)
    m = res.memory
    assert m.problem == "" and m.heap_free is not None and m.heap_free_low is not None
    assert 0 < m.heap_free_low <= m.heap_free <= PICO
    # (read at different turns: with what was allocated between, a little over the heap)
    assert m.heap_alloc is not None and m.heap_free + m.heap_alloc <= PICO * 1.1
    assert m.gc_collections is not None and m.gc_collections >= seconds * 5  # (every 100 ms)
    assert m.gc_overlaps == 0 and m.gc_longest_us and m.gc_longest_us > 0


def _check_grid(res: SoakResult, gc: dict[str, Any], periods_us: list[int]) -> None:
    """No collection, the firmware's or the allocator's, on an aligned instant while a map
    vouched for the grid; the allocator's own only in the start-up (STARTUP_US: the handshake,
    the rover's VL53L0X calibration, whose loop makes tens of KiB of garbage in one step),
    where the firmware cannot time them (the allocator collects where its threshold is
    reached)."""
    assert res.maps and res.align[0] == 1  # (the map was valid at the end)
    spans = [(a, b) for a, b, _kind in gc["log"]]
    assert len(spans) == gc["collections"]["req"] + gc["collections"]["auto"]
    assert grid_hits(spans, periods_us, res.maps, MAP_LIFE_US) == []
    late = [x for x in gc["log"] if x[2] == "auto" and x[0] >= STARTUP_US]
    assert late == [], late


ROVER_ALIGNED = ["compass", "wheel_l", "wheel_r"]  # 50 Hz: an instant every 20 ms
RIG_ALIGNED = ["imu", "dist_ir", "wheel"]  # 100, 25 and 50 Hz: an instant every 10 ms
SOAKS: dict[str, Callable[[], Soaked]] = {
    "rover": lambda: _soaked("rover.py", ROVER_ALIGNED, _rover_commands, [(2, 3), (6, 7)]),
    "rig": lambda: _soaked("thesis-rig.py", RIG_ALIGNED, _rig_commands, [(2, 3)]),
}


@pytest.fixture(scope="module")
def soaks(request: pytest.FixtureRequest) -> Iterator[dict[str, Future[Soaked]]]:
    """The boards' soaks selected in this run, side by side (a simulator is one node process,
    one core: both at once take the longer one's time; simulated time is the simulation's, so
    a neighbour changes nothing but how long it takes), all done before the first test looks
    (no host of one still reading when the other's test ends)."""
    wanted = {item.name for item in request.session.items}
    with ThreadPoolExecutor(len(SOAKS)) as pool:
        runs = {name: pool.submit(run) for name, run in SOAKS.items()
                if any(f"_{name}_runs_ten" in test for test in wanted)}  # fmt: skip
        wait(runs.values())
        yield runs


@pytest.mark.timeout(900)  # (ten simulated minutes: a few minutes here, both boards at once)
def test_the_rover_runs_ten_simulated_minutes_in_a_picos_heap(
    soaks: dict[str, Future[Soaked]],
) -> None:
    res, gc, sim = soaks["rover"].result()
    _check_soak(res, sim, {"compass": 50, "wheel_l": 50, "wheel_r": 50, "sonar": 10,
                               "tof": 10, "gps": 1})  # fmt: skip
    assert res.commands > 0 and res.valid["motor_l"] > 0 and res.valid["mast"] > 0
    _check_grid(res, gc, [20_000])


@pytest.mark.timeout(900)
def test_the_thesis_rig_runs_ten_simulated_minutes_in_a_picos_heap(
    soaks: dict[str, Future[Soaked]],
) -> None:
    res, gc, sim = soaks["rig"].result()
    _check_soak(res, sim, {"imu": 100, "dist_ir": 25, "wheel": 50, "sonar": 10})
    assert res.commands > 0 and res.valid["camera"] > 0 and res.align[3] > 0  # timed calls ran
    _check_grid(res, gc, [10_000, 40_000, 20_000])


def test_a_board_file_too_big_for_a_pico_runs_out_of_heap_there(tmp_path: Path) -> None:
    """The check flash makes is the simulator's verdict too: a board file whose estimate is
    over a Pico's heap (deploy/heap.py) fails with MemoryError under it."""
    big = tmp_path / "big.py"
    entries = [
        {"name": f"imu{i}", "id": i, "driver": "mpu6050", "bus": "i2c0", "rate_hz": 10}
        for i in range(60)
    ]
    board = {"name": "big", "mcu": "rp2040", "buses": {"i2c0": {"id": 0, "scl": 5, "sda": 4}},
             "transducers": entries}  # fmt: skip
    big.write_text("BOARD = " + json.dumps(board) + "\n")
    dry = subprocess.run(
        [sys.executable, "-m", "missing_link", "flash", str(big), "--port", "/dev/null",
         "--dry-run"], capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert dry.returncode == 2 and "heap" in dry.stderr, dry.stderr
    with pytest.raises(RuntimeError, match="MemoryError"):
        FastSim(big, PICO).close()


def test_a_host_slower_than_the_simulation_still_gets_its_turn() -> None:
    """The simulation runs at most --lead-ms past the host's last bytes; a host that comes to
    wait for its next turn when the simulation is there already (a loaded machine) must get it:
    waiting for ``TURN_US`` more was a deadlock (a CI run's soak stood still for 15 minutes)."""
    sim = FastSim(BOARDS / "thesis-rig.py", PICO, lead_ms=200)
    try:
        with Board(open_transport(sim.url), timeout=30.0) as board:
            board.handshake()
            board.clock_exchange(30)  # (the host's last bytes)
            assert wait_for(lambda: sim.figure("held"), 30)  # the simulation at its lead
            held_at = int(sim.figure("time"))
            done = threading.Event()
            threading.Thread(target=lambda: (wait_turn(sim, TURN_US), done.set()),
                             daemon=True).start()  # fmt: skip
            assert done.wait(10), "the host's turn never came"
            assert int(sim.figure("time")) == held_at  # (nothing moved it on meanwhile)
            board.clock_exchange(30)  # its bytes: the simulation goes on
            assert wait_for(lambda: int(sim.figure("time")) > held_at, 10)
    finally:
        sim.close()
