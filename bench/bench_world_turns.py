"""What a world costs a virtual board, two trees of the code paired in one run (issue 47.6): the
example rover as `missing-link board --file` (bench_world.py's scene: 1 m from its wall, its
rangers blocked there), at rest and driving (duty 0.5), and without a world (the reference),
each case under each tree's ``src`` in turn (PYTHONPATH: ``--before`` against this checkout's),
``--rounds`` times alternating.  Per case: the board's CPU (its process and node under it, from
/proc, % of a core over the window) and what does not move with the machine's load, counted in
the board's process: the firmware's loop turns and sleeps (its link's waits) a second
(CPython's Firmware; under MicroPython the firmware is node's, not counted here; a turn near a
timed call spins without a sleep, so turns move with the load, sleeps less), and the world's
batches asked and gone back over (rewound) a second (worldlink.py's ahead, as either tree
calls it); on CPython, the CPU of the world's pumps (time.thread_time, % of a core: its ticks,
feed calls and edges with the firmware's handlers).  Each figure is the median over the rounds.

    .venv/bin/python bench/bench_world_turns.py --before OLD/src [--seconds 15] [--rounds 2] \
        [--runtimes cpython,micropython]
"""

from __future__ import annotations

import argparse
import json
import os
import runpy
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
SRC = HERE.parent / "src"
COUNTS = ("turns", "sleeps", "batches", "rewound", "pump_us")


def counting_board(out: str, argv: list[str]) -> None:
    """``missing-link board ARGV`` in this process, its world's calls counted into ``out`` (a
    JSON file, rewritten every 0.2 s)."""
    from missing_link.board.firmware import Firmware
    from missing_link.virtual import world_cpython, worldlink

    counts = dict.fromkeys(COUNTS, 0)
    turn, ahead, init = Firmware._turn, worldlink.WorldLink.ahead, Firmware.__init__
    last: dict[int, int] = {}

    def counted_init(self: Any, *args: Any, **kwargs: Any) -> None:
        init(self, *args, **kwargs)
        wait = self.link.wait

        def counted_wait(us: int) -> None:
            counts["sleeps"] += 1
            wait(us)

        self.link.wait = counted_wait

    pump = world_cpython.CPythonWorld.pump

    def timed_pump(self: Any) -> None:
        t0 = time.thread_time_ns()
        pump(self)
        counts["pump_us"] += (time.thread_time_ns() - t0) // 1000

    def counted_turn(self: Any) -> None:
        counts["turns"] += 1
        turn(self)

    def counted_ahead(self: Any, now: int, used: int, values: list[int]) -> Any:
        counts["batches"] += 1
        counts["rewound"] += used < last.get(id(self), 0)
        ticks = ahead(self, now, used, values)
        last[id(self)] = len(ticks)
        return ticks

    Firmware._turn = counted_turn  # type: ignore[method-assign]
    world_cpython.CPythonWorld.pump = timed_pump  # type: ignore[method-assign]
    Firmware.__init__ = counted_init  # type: ignore[method-assign]
    worldlink.WorldLink.ahead = counted_ahead  # type: ignore[method-assign]

    def dump() -> None:
        while True:
            Path(out + ".new").write_text(json.dumps(counts))
            os.replace(out + ".new", out)
            time.sleep(0.2)

    threading.Thread(target=dump, daemon=True).start()
    sys.argv = ["missing-link", *argv]
    runpy.run_module("missing_link", run_name="__main__", alter_sys=True)


def measure(src: str, runtime: str, world: bool, duty: float, seconds: float) -> dict[str, float]:
    from bench_world import ROVER, drive, tree_cpu_s, world_file
    from missing_link.daemon import Daemon
    from missing_link.daemon.config import BoardSpec, Config

    out = tempfile.mktemp(prefix="world-counts-")
    argv = ["board", "--file", str(ROVER), "--runtime", runtime, "--listen", "tcp://127.0.0.1:0",
            "--world", str(world_file(runtime)) if world else "none"]  # fmt: skip
    env = {**os.environ, "PYTHONPATH": src}
    cmd = [sys.executable, __file__, "--as-board", out, *argv]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                            text=True)  # fmt: skip
    assert proc.stdout is not None
    line = proc.stdout.readline()
    if not line.startswith("LISTENING "):
        proc.kill()
        raise SystemExit(f"the rover ({runtime}, {src}) did not come up: {line!r}")

    def counts() -> dict[str, int]:
        got: dict[str, int] = json.loads(Path(out).read_text())
        return got

    try:
        spec = BoardSpec(line.split()[1], timeout=3.0, handshake_timeout=20.0)
        with Daemon(Config(boards=[spec])) as d:
            if not d.wait_until_up(60):
                raise SystemExit(f"no daemon on the rover ({runtime}): {d.status()}")
            drive(d, duty)
            time.sleep(3.0)  # (settled: the wheels up to speed)
            n0, c0, t0 = counts(), tree_cpu_s(proc.pid), time.monotonic()
            while time.monotonic() - t0 < seconds:
                time.sleep(0.5)
                drive(d, duty)
            n1, c1, t1 = counts(), tree_cpu_s(proc.pid), time.monotonic()
    finally:
        proc.terminate()
        proc.wait(15)
        Path(out).unlink(missing_ok=True)
    span = t1 - t0
    return {"cpu": (c1 - c0) / span * 100, **{k: (n1[k] - n0[k]) / span for k in COUNTS}}


CASES = {"no world (reference)": (False, 0.5), "at rest": (True, 0.0),
         "driving (duty 0.5)": (True, 0.5)}  # fmt: skip


def main() -> None:
    if len(sys.argv) > 2 and sys.argv[1] == "--as-board":
        return counting_board(sys.argv[2], sys.argv[3:])
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--before", required=True, help="the other tree's src (PYTHONPATH)")
    ap.add_argument("--seconds", type=float, default=15.0)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--runtimes", default="cpython,micropython")
    a = ap.parse_args()
    sys.path.insert(0, str(HERE))
    trees = {"before": a.before, "after": str(SRC)}
    print(f"load average at the start: {os.getloadavg()[0]:.2f}")
    print("| runtime | rover | tree | board's CPU, % of a core (each round) | turns/s | sleeps/s | "
          "batches/s | rewound/s | pumps' CPU, % of a core |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|")
    for runtime in a.runtimes.split(","):
        runs: dict[tuple[str, str], list[dict[str, float]]] = {}
        for _ in range(a.rounds):  # (alternating: a load that comes and goes hits all alike)
            for what, (world, duty) in CASES.items():
                for tree, src in trees.items():
                    got = measure(src, runtime, world, duty, a.seconds)
                    runs.setdefault((what, tree), []).append(got)
        for (what, tree), got in runs.items():
            med = {k: statistics.median(r[k] for r in got) for k in ("cpu", *COUNTS)}
            each = ", ".join(f"{r['cpu']:.2f}" for r in got)
            cpu = f"{med['cpu']:.2f} ({each})"
            rates = f"{med['turns']:.0f} | {med['sleeps']:.0f} | {med['batches']:.1f}"
            rewound, pumps = f"{med['rewound']:.1f}", f"{med['pump_us'] / 1e4:.2f}"
            print(f"| {runtime} | {what} | {tree} | {cpu} | {rates} | {rewound} | {pumps} |")
    print(f"load average at the end: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
