"""The world model's tick, in µs of CPU (issue 47.6): the example rover's world link (its
default world, as `missing-link board --file examples/boards/rover.py` builds it, worldlink.py)
ticked at rest and driving (duty 0.5 on both motors, the rover off its walls), hot (one tick
after another), cold (a 10 ms sleep before each, as a runtime that wakes the world every tick:
the interpreter comes back to the tick's code and data), and in batches after a 100 ms sleep
(WorldLink.ahead, as the runtimes ask for them now: up to 10 ticks, all used), per tick.
Per case the median of ``--ticks`` ticks' `time.thread_time` around the link's tick, and in a
second pass around the model's (World.step; its clock reads would add to the first); each child
process builds its own worlds.  The reference is another revision's src (``--against REV``:
`git archive` into a temporary directory; ``--model-only``: this tree's src with REV's model,
src/missing_link/world, the link the same in both), measured in the same run, the two
alternating ``--rounds`` times; each figure the median of the rounds.

    .venv/bin/python bench/bench_world_tick.py [--against REV] [--model-only] [--rounds 3] \
        [--ticks 300]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from io import BytesIO
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
ROVER = ROOT / "examples" / "boards" / "rover.py"
CASES = ("at rest, hot", "at rest, cold", "driving, hot", "driving, cold", "driving, batch")


def measure(ticks: int) -> dict[str, tuple[float, float]]:
    """Each case's (link tick, of it World.step), median µs of CPU a tick, in this process."""
    from missing_link.deploy.boardfile import load_board_file
    from missing_link.virtual.worldlink import WorldLink
    from missing_link.world.spec import WorldSpec
    from missing_link.world.world import World

    board = dict(load_board_file(ROVER).board)
    steps: list[float] = []
    plain = World.step

    def step(self: World, *args: Any, **kw: Any) -> Any:
        t0 = time.thread_time()
        try:
            return plain(self, *args, **kw)
        finally:
            steps.append(time.thread_time() - t0)

    def run(duty: float, n: int, sleep: float, batch: bool) -> float:
        link = WorldLink(World(WorldSpec(), board, 0), board)
        values = [150000 + round(duty * 10000) if fn == "motor" else 0 for fn, _ in link.reads]
        ticks: list[float] = []
        for _ in range(n):
            if sleep:  # (a sleep of 0 is a system call too: the tick after it is not hot)
                time.sleep(sleep)
            now = link.due_us()
            t0 = time.thread_time()
            if batch:
                made = len(link.ahead(now, link.batch, values))
            else:
                made = len(link.tick(now, values)[:1])  # (one tick)
            ticks.append((time.thread_time() - t0) / made)
        return statistics.median(ticks) * 1e6

    def case(duty: float, n: int, sleep: float, batch: bool) -> tuple[float, float]:
        tick = run(duty, n, sleep, batch)
        World.step = step  # type: ignore[method-assign]
        try:
            steps.clear()
            run(duty, n, sleep, batch)
        finally:
            World.step = plain  # type: ignore[method-assign]
        return tick, statistics.median(steps) * 1e6

    return {
        "at rest, hot": case(0.0, ticks * 5, 0.0, False),
        "at rest, cold": case(0.0, ticks, 0.01, False),
        "driving, hot": case(0.5, ticks * 5, 0.0, False),
        "driving, cold": case(0.5, ticks, 0.01, False),
        "driving, batch": case(0.5, ticks // 5, 0.1, True),
    }


def reference_src(rev: str, into: Path, model_only: bool) -> Path:
    """``rev``'s src tree, unpacked under ``into`` (``model_only``: this tree's, its model
    ``rev``'s)."""
    part = "src/missing_link/world" if model_only else "src"
    if model_only:
        shutil.copytree(ROOT / "src", into / "src", ignore=shutil.ignore_patterns("__pycache__"))
        shutil.rmtree(into / part)
    tar = subprocess.run(["git", "-C", str(ROOT), "archive", rev, part], capture_output=True,
                         check=True).stdout  # fmt: skip
    with tarfile.open(fileobj=BytesIO(tar)) as t:
        t.extractall(into, filter="data")
    return into / "src"


def child(src: Path, ticks: int) -> dict[str, list[float]]:
    env = {**os.environ, "PYTHONPATH": str(src)}
    out = subprocess.run([sys.executable, __file__, "--child", str(ticks)], env=env,
                         capture_output=True, text=True, check=True).stdout  # fmt: skip
    got: dict[str, list[float]] = json.loads(out)
    return got


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--against", default="main", help="the reference revision (default main)")
    ap.add_argument("--model-only", action="store_true", help="REV's world/ in this tree's src")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--ticks", type=int, default=300)
    ap.add_argument("--child", type=int, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        print(json.dumps(measure(a.child)))
        return
    runs: dict[str, list[dict[str, list[float]]]] = {"ref": [], "this": []}
    with tempfile.TemporaryDirectory() as tmp:
        ref = reference_src(a.against, Path(tmp), a.model_only)
        for _ in range(a.rounds):  # (alternating: a load that comes and goes hits both alike)
            runs["ref"].append(child(ref, a.ticks))
            runs["this"].append(child(ROOT / "src", a.ticks))
    load = os.getloadavg()[0]
    print(f"world link tick, µs of CPU (median of {a.rounds} rounds; load {load:.1f} at the end)")
    against = f"{a.against}'s model" if a.model_only else a.against
    print(f"| case | {against}: link tick | of it World.step | this tree: link tick | "
          "of it World.step | link tick, change |")  # fmt: skip
    print("|---|---|---|---|---|---|")
    for c in CASES:
        ref_tick, ref_step = (statistics.median(r[c][i] for r in runs["ref"]) for i in (0, 1))
        tick, step = (statistics.median(r[c][i] for r in runs["this"]) for i in (0, 1))
        print(f"| {c} | {ref_tick:.1f} | {ref_step:.1f} | {tick:.1f} | {step:.1f} | "
              f"{(tick - ref_tick) / ref_tick * 100:+.0f} % |")  # fmt: skip


if __name__ == "__main__":
    main()
