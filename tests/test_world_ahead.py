"""The world's ticks computed ahead (worldlink.py's ahead, as node asks for them under
MicroPython: worldtick.mjs) are the ticks one at a time (its tick, as CPython and AVR ask for
them), to the bit: a runtime that takes a batch's ticks at their times while the actuators hold,
and asks again when they change or when it comes a whole tick late, gets the same feed calls and
edges as a link ticked at the same times with the same reads and the same pushes, through the
world file's events, late ticks and a pause the world stands still for."""

from __future__ import annotations

import ast
import random
from pathlib import Path
from typing import Any

from missing_link.virtual.worldlink import Ahead, WorldLink
from missing_link.world.world import World
from missing_link.world.worldfile import parse

ROOT = Path(__file__).resolve().parent.parent
ROVER: dict[str, Any] = ast.literal_eval(
    (ROOT / "examples" / "boards" / "rover.py").read_text().split("BOARD = ", 1)[1]
)
WORLD = """
[start]
x_m = 3.0
[parts.sonar]
on = "mast"
[[events]]
at_s = 0.5
kind = "block"
part = "sonar"
distance_m = 0.3
for_s = 0.4
[[events]]
at_s = 1.0
kind = "slip"
part = "wheel_l"
fraction = 0.5
for_s = 0.5
[[events]]
at_s = 1.5
kind = "fail"
part = "imu"
mode = "stuck"
for_s = 0.3
[[events]]
at_s = 2.0
kind = "fail"
part = "compass"
for_s = 0.3
[[events]]
at_s = 2.5
kind = "bump"
"""
PUSHES = {40: ("push", {"dx_m": 0.1}), 90: ("turn", {"deg": 30}), 91: ("tilt", {"roll_deg": 5}),
          300: ("place", {"x_m": 0.0, "y_m": 1.0})}  # fmt: skip
Step = tuple[int, list[int], list[tuple[str, dict[str, Any]]]]


def arrivals(n: int) -> list[Step]:
    """A runtime's visits: its clock in whole ms, 1 to 5 ms apart, now and then a whole tick or
    two late, once 1.5 s (a pause); its motors and stepper commanded anew now and then."""
    rng = random.Random(5)
    now, duty, steps, out = 0, 0, 0, []
    for k in range(n):
        now += 1000 * rng.choice([1, 2, 3, 4, 5, 5, 5, 23]) + (1_500_000 if k == 500 else 0)
        if rng.random() < 0.01:
            duty = rng.choice([-8000, 0, 5000, 10000])
        if rng.random() < 0.01:
            steps += rng.choice([-3000, 3000, 6000])
        motor = (1 if duty else 0) * 100000 + 50000 + duty
        full = {"motor": motor, "servo": 1500, "stepper": steps, "stepper_on": 1}
        out.append((now, full, [PUSHES[k]] if k in PUSHES else []))
    return out  # type: ignore[return-value]


def link() -> WorldLink:
    return WorldLink(World(parse(WORLD, "room.toml"), ROVER, 0, seed=3), ROVER)


def test_ticks_ahead_are_the_ticks_one_at_a_time() -> None:
    world = link()
    runtime, got, done = Ahead(world), [], []  # done: (time, reads, pushes before) of each tick
    pushed: list[tuple[str, dict[str, Any]]] = []
    fresh_n = 0
    for now, full, pushes in arrivals(2000):
        for kind, args in pushes:
            world.push(kind, args)
        pushed += pushes
        if now < runtime.due_us():
            continue
        values = [full[fn] for fn, _ in world.reads]
        asked = runtime.batch
        tick = runtime.tick(now, values)
        fresh = runtime.batch is not asked  # (a new batch: the pushes since went into its first)
        fresh_n += fresh
        got.append(tick)
        done.append((tick[0], values, pushed if fresh else []))
        pushed = pushed if not fresh else []
    one = link()
    want = []
    for t, values, before in done:
        for kind, args in before:
            one.push(kind, args)
        want.append((t, *one.tick(t, values)))
    assert len(got) > 700 and sum(bool(e) for _t, _c, e in got) > 300
    assert sum(len(b) for *_, b in done) == len(PUSHES)
    assert got == want
    # (the batched world is ahead by the rest of its batch: asked from where the runtime is)
    last = max(runtime.due_us(), one.due_us())
    assert world.ahead(last, runtime.used, values)[0] == (last, *one.tick(last, values))
    assert world.skips == one.skips == 1
    assert len(got) / 10 < fresh_n < len(got) / 2  # (batches used whole, and asked anew)
