"""Simulated time (host.mjs --fast, fastclock.mjs): the firmware's clock moves within a step by
the step's CPU time, as a board's runs on while its loop works (issue 36.4: a clock that stood
still put a turn's work after its last reading, where the firmware asks for a collection, so the
simulator's log had collections holding an instant the firmware could not see coming)."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
FASTCLOCK = ROOT / "src" / "missing_link" / "virtual" / "world" / "fastclock.mjs"
pytestmark = [pytest.mark.micropython, pytest.mark.slow]

# One step that works 3 ms of CPU time, reads the clock's CPU time (as simtime.ticks_us does,
# moving the firmware's clock by it: `slept`), then ends; what the step moved `now` by and the
# bound on the CPU time no read saw (from just before the read to after the step returned).
STEP = """
import { FastClock } from %s;
const cpuUs = () => { const u = process.cpuUsage(); return u.user + u.system; };
const clock = new FastClock(1);
let seen = 0, before = 0, between = -1;
clock.step(() => {
  between = clock.cpu();
  const c = cpuUs();
  while (cpuUs() - c < 3000);  // the turn's work
  before = cpuUs();
  seen = clock.cpu();
  clock.mark();
  return `${seen} 0 0 0 0 -1|`;
});
const end = cpuUs();
const outside = clock.cpu();
// (to the step's end, not to mark(): the CPU time after mark() is charged as a collection
// nobody asked for may have run there, fastclock.mjs's step)
const unseen = end - before;
console.log(JSON.stringify({ now: clock.now, seen, unseen, between, outside }));
"""


def test_the_firmwares_clock_moves_by_its_steps_cpu_time_within_the_step() -> None:
    if shutil.which("node") is None:
        pytest.skip("node is required: run `make node`")
    script = STEP % json.dumps(FASTCLOCK.as_uri())
    out = subprocess.run(["node", "--input-type=module", "-e", script], capture_output=True,
                         text=True, timeout=60, check=True)  # fmt: skip
    got = json.loads(out.stdout)
    assert 0 <= got["between"] <= got["seen"]  # (the clock only moves on)
    assert got["seen"] >= 3000  # the work, seen by a read in the step
    # the step moved the clock by what its reads saw plus what they did not: once, not twice
    assert got["seen"] <= got["now"] <= got["seen"] + got["unseen"] + 1
    assert got["outside"] == got["seen"]  # (between steps the clock does not move)
