"""Node's side of the world under MicroPython (virtual/world/worldtick.mjs: the world's ticks taken
a batch at a time from world_mpy.py, made one by one at their times while the actuators hold) feeds
the board what the world's ticks one at a time give (worldlink.py's tick, as CPython and AVR ask
for them), to the bit.  WorldTick runs in node as under MicroPython, against the real world over
its pipes (NodeWorld), with a recorder for worldfeed.py and a script's clock and actuators
(tests/worldtick_driver.mjs): the Mega rover (its battery, servo and stepper too), firmware steps
0.25 to 31 ms apart from just before the port's 2^30 µs wrap, a little and a whole tick or more
late, once a pause the world stands still for, the actuators commanded anew (some changes undone
before the next tick), a controller hunting (the wheels back and forth), the world file's events.
At each step node makes every tick due by then: under the same actuators at its own time, after
a change at the board's (as a tick one at a time sees it); its feed calls are those of a link
ticked one at a time at that time with the step's reads, and the encoders' edges come at their
times, those before a tick first (worldfeed.steps_at: a run of one encoder's edges a call)."""

from __future__ import annotations

import json
import random
import shutil
import subprocess
from collections import Counter
from pathlib import Path
from typing import Any

import pytest

from missing_link.deploy.boardfile import load_board_file
from missing_link.virtual.world_mpy import NodeWorld
from missing_link.virtual.worldlink import MAX_CATCHUP_US, Edge, WorldLink
from missing_link.world.world import World
from missing_link.world.worldfile import parse

pytestmark = pytest.mark.slow

HERE = Path(__file__).resolve().parent
MEGA: dict[str, Any] = load_board_file(HERE.parent / "examples" / "boards" / "rover-mega.py").board
#: the world's events while the script runs, and a small pack (its charge falls a millivolt or
#: so a batch: a world that forgot where the pack was reads another voltage)
WORLD = """
[start]
x_m = 3.0
[battery]
capacity_ah = 0.05
[parts.sonar]
on = "mast"
[[events]]
at_s = 0.6
kind = "block"
part = "sonar"
distance_m = 0.3
for_s = 0.4
[[events]]
at_s = 1.1
kind = "slip"
part = "wheel_r"
fraction = 0.5
for_s = 0.5
[[events]]
at_s = 1.7
kind = "fail"
part = "imu"
mode = "silent"
for_s = 0.3
[[events]]
at_s = 2.3
kind = "fail"
part = "battery"
mode = "stuck"
for_s = 0.2
[[events]]
at_s = 3.0
kind = "bump"
"""
SEED = 7
WRAP = 1 << 30
Step = tuple[int, dict[str, int]]


def script(n: int) -> list[Step]:
    """``n`` firmware steps: the board's time (from near the port's 2^30 µs wrap) and the
    actuators' reads then."""
    rng = random.Random(4)
    now = WRAP - 700_000
    keys = [f"{fn} {a[0]}" for fn, a in _link().reads]
    act = dict.fromkeys(keys, 0)
    act.update({k: 50000 for k in keys if k.startswith("motor")})  # (duty 0, coast)
    out: list[Step] = []
    for k in range(n):
        hunting = n // 4 <= k < n // 4 + 100  # (a controller hunting, in a busy firmware)
        if hunting:
            now += rng.choice([6000, 9000, 15_000, 25_000, 31_000])
        else:
            now += rng.choice([1000] * 8 + [250, 2000, 3000, 5000, 9999, 10_000, 14_000, 23_000])
        now += 1_500_000 if k == n // 2 else 0  # (its host paused it)
        if rng.random() < 0.05:
            key = rng.choice(keys)
            if key.startswith("motor"):
                duty = rng.choice([-10000, -6000, 0, 3000, 7000, 10000])
                act[key] = rng.choice([0, 1, 1, 1, 2, 3]) * 100000 + 50000 + duty
            elif key.startswith("servo"):
                act[key] = rng.choice([-1, 900, 1500, 2100])
            elif key.startswith("stepper_on"):
                act[key] = 1 - act[key]
            else:
                act[key] += rng.choice([-400, 200, 800])
        if hunting:  # (the wheels back and forth, 60 ms each way)
            duty = 10000 if now // 60_000 % 2 else -10000
            act.update({m: 150000 + duty for m in keys if m.startswith("motor")})
        out.append((now, dict(act)))
    return out


def _link(start_us: int = 0) -> WorldLink:
    return WorldLink(World(parse(WORLD, "room.toml"), MEGA, start_us, SEED), MEGA)


def run_node(steps: list[Step]) -> tuple[list[tuple[int, list[list[Any]]]], NodeWorld]:
    """What WorldTick did at each step: the world's next due time after it, its feed calls."""
    node = shutil.which("node")
    if node is None:
        pytest.skip("node is required: run `make node`")
    world = NodeWorld(parse(WORLD, "room.toml"), MEGA, SEED, frozenset())
    with subprocess.Popen(
        [node, str(HERE / "worldtick_driver.mjs"), *world.node_args()],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        pass_fds=world.pass_fds,
    ) as proc:  # fmt: skip
        world.started()
        out, err = proc.communicate(json.dumps(steps), timeout=60)
    assert proc.returncode == 0 and world.failed is None, (err[-2000:], world.failed)
    return [(due, heard) for due, heard in json.loads(out)], world


def runs(queue: list[Edge], by: int) -> list[tuple[Any, ...]]:
    """worldfeed.steps_at's calls for the edges due ``by`` then (taken from ``queue``, in time
    order): each encoder's, a run of them the same way in one call from its first edge's time
    to its last's."""
    n = sum(1 for e in queue if e[0] <= by)
    edges, queue[:n] = queue[:n], []
    out: list[tuple[Any, ...]] = []
    for pin in dict.fromkeys(a for _t, a, _b, _d in edges):
        mine = [e for e in edges if e[1] == pin]
        i = 0
        while i < len(mine):
            j = i
            while j < len(mine) and mine[j][3] == mine[i][3]:
                j += 1
            t0, a, b, d = mine[i]
            out.append(("steps_at", a, b, d, j - i, t0 % WRAP, mine[j - 1][0] - t0))
            i = j
    return out


def in_order(calls: list[tuple[Any, ...]]) -> list[tuple[Any, ...]]:
    """``calls`` with each run of steps_at calls sorted (the order across encoders is not
    kept)."""
    out: list[tuple[Any, ...]] = []
    while calls:
        n = next((i for i, c in enumerate(calls) if c[0] != "steps_at"), len(calls))
        out += sorted(calls[:n]) + calls[n : n + 1]
        calls = calls[n + 1 :]
    return out


def opened(heard: list[list[Any]]) -> tuple[list[int], list[tuple[Any, ...]]]:
    """A step's ticks, by the world's due time when each read the actuators, and what it fed."""
    dues: list[int] = []
    fed: list[tuple[Any, ...]] = []
    for i, c in enumerate(heard):
        if c[0] != "read":
            fed.append(tuple(c))
        elif i == 0 or heard[i - 1][0] != "read":
            dues.append(c[3])
    return dues, in_order(fed)


def test_node_feeds_what_the_world_ticked_one_at_a_time_gives() -> None:
    steps = script(3000)
    got, world = run_node(steps)
    one = _link(steps[0][0])
    due, queue, last = steps[0][0], list[Edge](), None
    seen: Counter[str] = Counter()
    for k, ((now, act), (node_due, heard)) in enumerate(zip(steps, got, strict=True)):
        dues, fed = opened(heard)
        values = [act[f"{fn} {a[0]}"] for fn, a in one.reads]
        want = [("attach", *a) for _fn, a in one.attach()] if k == 0 else []
        for d, after in zip(dues, [*dues[1:], node_due][: len(dues)], strict=True):
            t = after - one.tick_us  # (its time: the next is due at its end)
            assert d == due <= t <= now, (k, now, due, d, t)
            if values != last:  # (a change is seen now, as by a tick one at a time)
                assert t == now, (k, now, d, t)
            elif now - d <= MAX_CATCHUP_US:  # (the same actuators: the tick due, at its time)
                assert t == d, (k, now, d, t)
            want += runs(queue, d - 1)  # (the edges before the tick first)
            calls, edges = one.tick(t, values)
            want += [(fn, *args) for fn, args in calls]
            queue = sorted(queue + edges, key=lambda e: e[0])
            assert one.due_us() == after, k
            seen["changed" if values != last else "late" if t < now else "on time"] += 1
            due, last = after, values
        seen["caught up"] += len(dues) > 1
        assert due == node_due > now, (k, now, due, node_due)  # (every tick due made)
        want += runs(queue, now)
        assert fed == in_order(want), f"step {k} at {now}: node fed\n{fed}\none at a time\n{want}"
    # (the script took every path: actuators changed at many ticks, ticks made late at their
    # time and several at a step, the sensors fed, edges delivered and an encoder's both ways at
    # one step, the pause)
    assert len(seen) == 4 and min(seen.values()) > 50, seen
    fed_n = Counter(c[0] for _d, heard in got for c in heard)
    assert min(fed_n[fn] for fn in ("volts", "ranger", "imu", "fix", "off")) > 1, fed_n
    assert min(fed_n[fn] for fn in ("volts", "ranger", "imu", "steps_at")) > 200, fed_n
    runs_at = [{tuple(c[1:4]) for c in heard if c[0] == "steps_at"} for _due, heard in got]
    ways = Counter((k, a) for k, pins in enumerate(runs_at) for a, _b, _d in pins)
    assert sum(n > 1 for n in ways.values()) > 3  # (an encoder's edges both ways at one step)
    assert one.state()["skips"] == world.state()["skips"] == 1
