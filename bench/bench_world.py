"""What a world costs a virtual board (issue 47.6): the example rover (on AVR rover-mega.py)
as `missing-link board --file`, on each runtime, with `--world none` (the reference: the same
board without a world, measured in the same run), in its world at rest, and in it
driving (duty 0.5 on both motors: its wheels turn, its encoders' edges flow, it meets the wall
and its wheels spin on), a daemon taking its samples at their rates.  Per case: the board's CPU
(its process and those under it, node or simavr's rig, from /proc, in % of one core over the
window) and of it the board's own process (under MicroPython and AVR: the world's side), and
what the firmware says of itself: its heap (MicroPython: allocated, and free at the lowest; AVR:
its stack's free at the lowest) and its IMU's sample timing (the period between two board
stamps: mean and worst).  The cases alternate, ``--rounds`` times; each figure is the median
over the rounds, and the world's cost the median of each case less its round's reference.  The
world starts the rover 1 m from its wall (NEAR_WALL) with its rangers held at 1000 mm, the
scene the simulator's parts give the reference.  Then the world link
alone in this process (worldlink.py ticked as a runtime ticks it, driving), per simulated
second.  (The board's heap and sample timing with and without its world, in simulated time and
the same on every run: tests/test_world_beside.py.)  Driving
costs the firmware its encoders' interrupts too (some 1000 edges a second), as on a board;
and under MicroPython the simulator's own work an edge, paired with each edge a call, and an
edge's whole cost with the firmware's own handler.

    .venv/bin/python bench/bench_world.py [--seconds 20] [--rounds 2] \
        [--runtimes cpython,micropython,avr]
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config
from missing_link.topics import Update

ROVER = Path(__file__).resolve().parent.parent / "examples" / "boards" / "rover.py"
#: the AVR's rover (an ATmega2560 in simavr: rover-mega.py), its board's name
AVR_ROVER, NAMES = ROVER.with_name("rover-mega.py"), {"avr": "mega_rover"}
TICK_S = os.sysconf("SC_CLK_TCK")


def tree_cpu_s(pid: int, children: bool = True) -> float:
    """CPU seconds (user + system) of ``pid`` and (``children``) every live process under it."""
    parents: dict[int, int] = {}
    times: dict[int, float] = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
        except OSError:
            continue  # (gone meanwhile)
        parents[int(entry)] = int(fields[1])
        times[int(entry)] = (int(fields[11]) + int(fields[12])) / TICK_S
    ours, total = {pid}, 0.0
    if not children:
        return times.get(pid, 0.0)
    for p in sorted(parents):  # (children have larger pids here; a second pass catches the rest)
        if parents[p] in ours:
            ours.add(p)
    for p in sorted(parents):
        if parents[p] in ours:
            ours.add(p)
    for p in ours:
        total += times.get(p, 0.0)
    return total


#: the world of the bench: the default room, the rover 1 m from its wall (its rangers' front
#: edge), where the simulator's parts put a target without a world (1000 mm: pin_devices.py,
#: i2c_devices.py), so the firmware does the same work in both (a sonar that sees nothing in
#: reach waits out the HC-SR04's 38 ms echo: that is the scene's cost, not the world's).  Its
#: two rangers are blocked at that 1000 mm for good: driving, the rover reaches its wall in
#: some 4 s and its wheels spin on there, where the sonar sees less than its 2 cm and waited
#: out its timeout (24 ms of every 100, busy under node and simavr) in all but the first
#: seconds: 4 to 5 % of a core of the driving case's cost under MicroPython was that.  A
#: blocked ranger is still ray-cast (world.py): the world's work is the same.
NEAR_WALL = "[start]\nx_m = 3.88\n"
BLOCK = '[[events]]\nat_s = 0\nkind = "block"\npart = "{}"\ndistance_m = 1.0\n'
#: the rangers of each runtime's rover (the AVR's has no ToF)
RANGERS = {"avr": ("sonar",)}
WORLD_DIR = Path(tempfile.mkdtemp(prefix="bench-world-"))


def world_file(runtime: str) -> Path:
    path = WORLD_DIR / f"near-wall-{runtime}.toml"
    if not path.exists():
        rangers = RANGERS.get(runtime, ("sonar", "tof"))
        path.write_text(NEAR_WALL + "".join(BLOCK.format(r) for r in rangers))
    return path


def start(runtime: str, world: bool) -> tuple[subprocess.Popen[str], str]:
    file = AVR_ROVER if runtime == "avr" else ROVER
    cmd = [sys.executable, "-m", "missing_link", "board", "--file", str(file), "--runtime",
           runtime, "--listen", "tcp://127.0.0.1:0"]  # fmt: skip
    cmd += ["--world", str(world_file(runtime)) if world else "none"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    assert proc.stdout is not None
    line = proc.stdout.readline()
    if not line.startswith("LISTENING "):
        proc.kill()
        raise SystemExit(f"the rover ({runtime}) did not come up: {line!r}")
    return proc, line.split()[1]


def drive(d: Daemon, duty: float, name: str = "rover") -> None:
    for side in ("l", "r"):
        try:
            d.send(f"/{name}/motor_{side}/cmd", duty)
        except KeyError:  # (the board is away: its session comes back)
            print("(the rover was away: its motors not commanded once)", file=sys.stderr)


def measure(runtime: str, world: bool, duty: float, seconds: float) -> dict[str, float]:
    proc, url = start(runtime, world)
    imu: list[Update] = []
    name = NAMES.get(runtime, "rover")
    try:
        with Daemon(Config(boards=[BoardSpec(url, timeout=3.0, handshake_timeout=20.0)])) as d:
            if not d.wait_until_up(60):
                raise SystemExit(f"no daemon on the rover ({runtime}): {d.status()}")
            d.subscribe(f"/{name}/imu", imu.append, queue=0)
            drive(d, duty, name)
            time.sleep(3.0)  # (settled: the wheels up to speed)
            n0, c0, t0 = len(imu), tree_cpu_s(proc.pid), time.monotonic()
            own0 = tree_cpu_s(proc.pid, children=False)
            while time.monotonic() - t0 < seconds:
                time.sleep(0.5)
                drive(d, duty, name)  # (as a controller does: its failsafe stays quiet)
            c1, t1, n1 = tree_cpu_s(proc.pid), time.monotonic(), len(imu)
            own1 = tree_cpu_s(proc.pid, children=False)
            status = d.status()[0]
    finally:
        proc.terminate()
        proc.wait(15)
    got = imu[n0:n1]
    periods = [(b.board_us[0] - a.board_us[0]) / 1000 for a, b in itertools.pairwise(got)]
    return {
        "cpu": (c1 - c0) / (t1 - t0) * 100,
        "own": (own1 - own0) / (t1 - t0) * 100,
        "period_ms": statistics.mean(periods),
        "worst_ms": max(periods),
        "heap_alloc": status.get("heap_alloc", -1),
        # (the AVR's: its stack's lowest free, a2jMemory)
        "heap_free_low": status.get("heap_free_low", status.get("stack_free_low", -1)),
    }


def world_alone(sim_s: float) -> float:
    """The world link's own CPU (this process) per simulated second, % of a core: the rover's
    default world ticked as a runtime ticks it, its motors at duty 0.5 (the feed's integers)."""
    from missing_link.deploy.boardfile import load_board_file
    from missing_link.virtual.worldlink import WorldLink
    from missing_link.world.spec import WorldSpec
    from missing_link.world.world import World

    board = dict(load_board_file(ROVER).board)
    link = WorldLink(World(WorldSpec(), board, 0), board)
    values = [100000 + 55000 if fn == "motor" else 0 for fn, _a in link.reads]  # (drive, 0.5)
    c0 = time.process_time()
    now = 0
    while now < sim_s * 1e6:
        link.tick(now, values)
        now = link.due_us()
    return (time.process_time() - c0) / sim_s * 100


#: node's calls into MicroPython with small integers, as worldtick.mjs makes them: what they
#: leave in the interpreter's heap (the one the firmware has), garbage collection off meanwhile
CALL_PROBE = """
const { loadMicroPython } = await import(process.env.MPY_ENTRY);
const mp = await loadMicroPython({});
mp.runPython("import gc\\ndef f(i, a, b, c, d, e, g):\\n    return i\\n" +
  "def used():\\n    return gc.mem_alloc()");
const [f, used] = [mp.globals.get("f"), mp.globals.get("used")];
mp.runPython("gc.collect()\\ngc.disable()");
const before = used();
for (let k = 0; k < 10000; k++) f(3, 16384, -120, 7, 131, -262, 5);
console.log(used() - before);
"""


def feed_call_bytes() -> int:
    """Bytes left in MicroPython's heap by 10000 calls from node with seven small integers."""
    from missing_link.virtual.mpyboard import find_micropython

    node, entry = find_micropython()
    env = {**os.environ, "MPY_ENTRY": str(entry)}  # (not an argument: the module runs its REPL)
    r = subprocess.run([node, "--input-type=module", "-e", CALL_PROBE], env=env,
                       capture_output=True, text=True, timeout=60, check=True)  # fmt: skip
    return int(r.stdout.split()[-1])


#: the simulator's own work for an encoder edge in MicroPython (the firmware's handler a count
#: only): worldfeed.steps_at's run of edges, and the reference, each edge as worldfeed.step_at
#: (machine.encoder_steps and set_level: how steps_at delivered them before), alternating; and
#: steps_at with the firmware's own handler (the rover's quadrature driver, board/drivers), the
#: edge's whole cost in node: what the firmware's handler adds is the board's own work.  In
#: real time, as the bench's rovers run (the clock an edge's handler reads: heldtime.py)
EDGE_PROBE = """
const { loadMicroPython } = await import(process.env.MPY_ENTRY);
const { copyTree } = await import(process.env.MPFS);
const mp = await loadMicroPython({});
mp.FS.mkdir("/lib");
copyTree(mp, process.env.SIMWORLD, "/lib/simworld");
copyTree(mp, process.env.BOARD, "/lib/mlboard");
mp.runPython(`
import sys
sys.path.append('/lib')
import simworld.heldtime as heldtime
sys.modules['time'] = heldtime
import simworld.machine
sys.modules['machine'] = simworld.machine
import machine
from machine import Pin
from simworld import worldfeed
from mlboard.clock import default_clock
from mlboard.drivers.encoder import Quadrature
worldfeed.clock = heldtime
worldfeed.release = heldtime.release
N = [0]
def edge(pin):
    N[0] += 1
Pin(2, Pin.IN).irq(edge)
Pin(3, Pin.IN).irq(edge)
Q = Quadrature(machine, default_clock(), 6, 7)
def each(d, n):
    k = 0
    while k < n:
        worldfeed.step_at(1000 + k * 100, 2, 3, d)
        k += 1
`);
const [run, each] = [mp.globals.get("worldfeed").steps_at, mp.globals.get("each")];
const us = (f) => {
  const t = process.cpuUsage();
  for (let i = 0; i < 20; i++) f(i % 2 ? -1 : 1);
  const c = process.cpuUsage(t);
  return (c.user + c.system) / 20000;
};
const got = { run: [], each: [], firmware: [] };
for (let r = 0; r < 7; r++) {
  got.run.push(us((d) => run(2, 3, d, 1000, 1000, 100000)));
  got.each.push(us((d) => each(d, 1000)));
  got.firmware.push(us((d) => run(6, 7, d, 1000, 1000, 100000)));
}
console.log(JSON.stringify(got));
"""


def edge_us() -> tuple[float, float, float]:
    """µs of CPU an encoder edge takes in MicroPython: the simulator's work (steps_at, and each
    edge a call: the reference) and the edge's whole (steps_at to the firmware's quadrature
    handler), medians of seven alternating rounds of 20,000 edges."""
    from missing_link.virtual.mpyboard import find_micropython

    node, entry = find_micropython()
    src = Path(__file__).resolve().parent.parent / "src" / "missing_link"
    sim = src / "virtual" / "world"
    env = {**os.environ, "MPY_ENTRY": str(entry), "MPFS": (sim / "mpfs.mjs").as_uri(),
           "SIMWORLD": str(sim), "BOARD": str(src / "board")}  # fmt: skip
    r = subprocess.run([node, "--input-type=module", "-e", EDGE_PROBE], env=env,
                       capture_output=True, text=True, timeout=120, check=True)  # fmt: skip
    got = json.loads(r.stdout.split("\n")[-2])
    run, each, whole = (statistics.median(got[k]) for k in ("run", "each", "firmware"))
    return run, each, whole


def median(runs: list[dict[str, float]], key: str) -> float:
    return statistics.median(r[key] for r in runs)


def row(runtime: str, what: str, runs: list[dict[str, float]]) -> str:
    alloc = f"{median(runs, 'heap_alloc'):.0f}" if runs[0]["heap_alloc"] >= 0 else "-"
    low = f"{median(runs, 'heap_free_low'):.0f}" if runs[0]["heap_free_low"] >= 0 else "-"
    heap = f"{alloc} | {low}"
    cpu = f"{median(runs, 'cpu'):.2f} | {median(runs, 'own'):.2f}"
    timing = f"{median(runs, 'period_ms'):.2f} | {median(runs, 'worst_ms'):.1f}"
    return f"| {runtime} | {what} | {cpu} | {heap} | {timing} |"


REFERENCE = "--world none (reference)"
CASES = {REFERENCE: (False, 0.5), "its world, at rest": (True, 0.0),
         "its world, driving (duty 0.5)": (True, 0.5)}  # fmt: skip


def paired(runs: list[dict[str, float]]) -> str:
    """The median over rounds of a case's CPU less its round's reference's, and each round's
    (the spread: on a shared machine the load moves them)."""
    each = [r["cpu"] - r["reference"] for r in runs]
    return f"{statistics.median(each):+.2f} ({', '.join(f'{c:+.2f}' for c in each)})"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--runtimes", default="cpython,micropython,avr")
    a = ap.parse_args()
    print("| runtime | rover | board's CPU, % of a core | of it its own process | heap allocated, "
          "B | heap (AVR: stack) free at the lowest, B | IMU period, ms (50 Hz: 20) | worst, ms "
          "|")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|")
    costs: dict[str, list[str]] = {}
    for runtime in a.runtimes.split(","):
        runs: dict[str, list[dict[str, Any]]] = {k: [] for k in CASES}
        for _ in range(a.rounds):  # (alternating: a load that comes and goes hits all alike)
            for what, (world, duty) in CASES.items():
                runs[what].append(measure(runtime, world, duty, a.seconds))
            for case in runs.values():
                case[-1]["reference"] = runs[REFERENCE][-1]["cpu"]
        for what in CASES:
            print(row(runtime, what, runs[what]))
        costs[runtime] = [paired(runs[what]) for what in list(CASES)[1:]]
    print("\nthe world's cost, each case less the reference of its round (median over rounds; "
          "each round's):")  # fmt: skip
    for runtime, (rest, driving) in costs.items():
        print(f"  {runtime}: at rest {rest} % of a core, driving {driving}")
    print(f"\nthe world link alone (this process, driving): {world_alone(60):.2f} % of a core")
    if "micropython" in a.runtimes:
        print(
            f"\n10000 calls from node into MicroPython, 7 small integers each: "
            f"{feed_call_bytes()} B left in its heap"
        )
        run, each, whole = edge_us()
        print(f"an encoder edge, the simulator's work in MicroPython: {run:.1f} µs of CPU "
              f"(worldfeed.steps_at); each edge a call (the reference): {each:.1f} µs; "
              f"with the firmware's quadrature handler: {whole:.1f} µs")  # fmt: skip


if __name__ == "__main__":
    main()
