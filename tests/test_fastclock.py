"""Simulated time is simulated (host.mjs --fast: fastclock.mjs, simtime.py, simcost.py): the
firmware's clock moves, within a step too, by what its work costs on a Pico, as a board's runs
on while its loop works (issue 36.4: a clock that stood still put a turn's work after its last
reading, where the firmware asks for a collection), and by nothing else: not by the host's CPU
time or its clock (issue 42.1: a busy machine changed the soak's collections).  So the same
seeded simulation with the same host gives the same run, on a quiet machine or a busy one."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from missing_link.j2a import SifReceived
from missing_link.virtual.world import simcost

from .memory_soak import FastSim, soak

ROOT = Path(__file__).resolve().parent.parent
WORLD = ROOT / "src" / "missing_link" / "virtual" / "world"
RIG = ROOT / "examples" / "boards" / "thesis-rig.py"
PICO = 209_936
pytestmark = [pytest.mark.micropython, pytest.mark.slow]

# Steps given to the clock as mpyhost.py's _step reports them (SLEPT NS REQ AT CHARGED CLK0 AUTO
# DUE), one of them working the host's CPU for 20 ms: what the clock did.
STEPS = """
import { FastClock } from %s;
const clock = new FastClock();
const seen = [];
const step = (head, settled, work = 0) => {
  clock.step((now, ns) => {
    seen.push([now, ns]);
    const until = performance.now() + work;
    while (performance.now() < until);  // (the host's CPU, busy)
    clock.report(...head.split(" ").map(Number));
    return "";
  }, () => settled);
  return clock.nowNs;
};
const a = step("1234 567 0 0 0 0 0 -1", 0, 20);  // 1234.567 ms of work, the CPU busy 20 ms
const b = step("100 567 1 40 5000000 1000 0 -1", 5000300);  // a collection asked for at 40 µs
const c = step("100 867 0 0 0 2000 1 5000", 7000000);  // the allocator's, as it returned
clock.idle(c + 3000000);  // (nothing to do: to the deadline, 5 ms, but not past the limit)
const d = clock.nowNs;
clock.due = 2000;
clock.idle();
console.log(JSON.stringify({ a, b, c, d, e: clock.nowNs, seen, log: clock.log,
  collections: clock.collections }));
"""


def _node(script: str) -> Any:
    if shutil.which("node") is None:
        pytest.skip("node is required: run `make node`")
    out = subprocess.run(["node", "--input-type=module", "-e", script], capture_output=True,
                         text=True, timeout=60, check=True)  # fmt: skip
    return json.loads(out.stdout)


def test_the_clock_moves_by_what_the_step_says_it_cost_and_by_nothing_else() -> None:
    got = _node(STEPS % json.dumps((WORLD / "fastclock.mjs").as_uri()))
    # by the step's cost to the ns, not by the 20 ms of CPU it took here
    assert got["a"] == 1_234_567
    assert got["seen"][1] == [1234, 567]  # (the next step starts there, the ns below the µs)
    # a collection charged 5 ms at the call took 5.0003 ms: 300 ns more after the step; its
    # span from where it was asked for (the board clock's 1000 + 40 µs), as long as it took
    assert got["b"] == 1_234_567 + 100_000 + 300
    assert got["log"][0] == [1040, 1040 + 5001, "req"]
    # the allocator's: 7 ms after the step, from its end (the board clock's 2000 + 100 µs)
    assert got["c"] == got["b"] + 100_000 + 7_000_000
    assert got["log"][1] == [2100, 2100 + 7000, "auto"]
    assert got["collections"] == {"req": 1, "auto": 1}
    assert got["d"] == got["c"] + 3_000_000  # idle: to the limit, short of the 5 ms deadline
    assert got["e"] == got["d"] + 2_000_000  # ... then to the next deadline


# In the real interpreter with simtime as `time` (host.mjs --fast --run): what reads see.
READS = """
import time, machine
t = [time.ticks_us() for _ in range(4)]
adc = machine.ADC(26)
a = time.ticks_us()
adc.read_u16()
b = time.ticks_us()
print(t[1] - t[0], t[2] - t[1], t[3] - t[2], b - a)
"""


def test_a_read_sees_the_work_before_it(tmp_path: Path) -> None:
    """Each read costs a read (9.6 µs: reads land 9 or 10 µs apart, as on a board); an ADC
    conversion between two reads shows as the call and the conversion."""
    if shutil.which("node") is None:
        pytest.skip("node is required: run `make node`")
    script = tmp_path / "reads.py"
    script.write_text(READS)
    cmd = ["node", str(WORLD / "host.mjs"), str(RIG), "--fast", "--run", str(script)]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=60, check=True)
    d0, d1, d2, adc = map(int, out.stdout.split())
    read = simcost.READ_NS / 1000
    assert sorted({d0, d1, d2}) == [int(read), int(read) + 1] and d0 + d1 + d2 in (28, 29)
    want = (simcost.CALL_NS + simcost.ADC_NS + simcost.READ_NS) / 1000
    assert abs(adc - want) < 1


def _run(busy: bool) -> tuple[list[tuple[int, int, bytes]], dict[str, Any], Any]:
    """The thesis rig, seeded, for 20 simulated seconds with its host in lockstep and aligned
    sampling: every SIF as it came, the collections, the board's figures."""
    hog = subprocess.Popen([sys.executable, "-c", "while True: pass"]) if busy else None
    try:
        sim = FastSim(RIG, PICO, seed=7)
        try:
            stream: list[tuple[int, int, bytes]] = []

            def take(ev: SifReceived) -> None:
                stream.append((ev.cmd, ev.seq, ev.payload))

            res = soak(sim, 20, ["imu", "dist_ir", "wheel"], on_sif=take)
            gc = sim.figure("gc")
        finally:
            sim.close()
    finally:
        if hog is not None:
            hog.kill()
            hog.wait(10)
    return stream, gc, res.memory


def test_the_same_simulation_runs_the_same_beside_a_busy_process() -> None:
    quiet, busy = _run(busy=False), _run(busy=True)
    assert len(quiet[0]) > 3000  # (imu 100 Hz, wheel 50, dist_ir 25, sonar 10: 20 s)
    assert quiet[0] == busy[0]  # sample for sample: values, board stamps, seq
    assert quiet[1]["log"] == busy[1]["log"] and quiet[1]["log"]  # collection for collection
    assert quiet[2] == busy[2]  # and the board's own figures (a2jMemory)
