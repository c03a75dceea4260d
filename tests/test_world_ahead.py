"""The world's ticks computed ahead (worldlink.py's ahead, as node asks for them under
MicroPython: worldtick.mjs) are the ticks one at a time (its tick, as CPython and AVR ask for
them), to the bit: a runtime that takes a batch's ticks at their times while the actuators hold
(late too) and asks again when they change or the batch is used up gets the same feed calls and
edges as a link ticked at the same times with the same reads and the same pushes, through the
world file's events, late ticks and a pause the world stands still for.  So does a runtime that
makes any part of a batch (its first at least) and asks again at any time after, and the world's
state after a batch, and the link's counts, are theirs after those ticks one at a time: going
back forgets nothing (the pack's charge, the motors' current, the readings dropped).  A world
restored is, in every part, the world it was."""

from __future__ import annotations

import math
import random
from pathlib import Path
from typing import Any

from missing_link.deploy.boardfile import load_board_file
from missing_link.virtual.worldlink import Ahead, Tick, WorldLink
from missing_link.world.sensing import ImuReading
from missing_link.world.world import Actuation, Frame, World
from missing_link.world.worldfile import parse

ROOT = Path(__file__).resolve().parent.parent


def board(name: str) -> dict[str, Any]:
    return load_board_file(ROOT / "examples" / "boards" / name).board


ROVER = board("rover.py")
#: the rover with its battery and a servo (the rover's has none: no reading shows the pack)
MEGA = board("rover-mega.py")
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
Push = tuple[str, dict[str, Any]]
PUSHES: dict[int, Push] = {40: ("push", {"dx_m": 0.1}), 90: ("turn", {"deg": 30}),
                           91: ("tilt", {"roll_deg": 5}),
                           300: ("place", {"x_m": 0.0, "y_m": 1.0})}  # fmt: skip
Step = tuple[int, dict[str, int], list[Push]]


def arrivals(n: int) -> list[Step]:
    """A runtime's visits: its clock in whole ms, 1 to 5 ms apart, now and then a whole tick or
    two late, once 1.5 s (a pause); its motors and stepper commanded anew now and then."""
    rng = random.Random(5)
    now, duty, steps = 0, 0, 0
    out: list[Step] = []
    for k in range(n):
        now += 1000 * rng.choice([1, 2, 3, 4, 5, 5, 5, 23]) + (1_500_000 if k == 500 else 0)
        if rng.random() < 0.01:
            duty = rng.choice([-8000, 0, 5000, 10000])
        if rng.random() < 0.01:
            steps += rng.choice([-3000, 3000, 6000])
        motor = (1 if duty else 0) * 100000 + 50000 + duty
        full = {"motor": motor, "servo": 1500, "stepper": steps, "stepper_on": 1}
        out.append((now, full, [PUSHES[k]] if k in PUSHES else []))
    return out


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


#: the Mega rover's world: a small pack (its charge falls a millivolt or so a batch, its
#: reading a hundred with the motors' current) and the events of a run
POWER = """
[start]
x_m = 3.0
[battery]
capacity_ah = 0.05
[parts.sonar]
on = "mast"
[[events]]
at_s = 0.4
kind = "block"
part = "sonar"
distance_m = 0.3
for_s = 0.3
[[events]]
at_s = 0.9
kind = "slip"
part = "wheel_r"
fraction = 0.5
for_s = 0.5
[[events]]
at_s = 1.6
kind = "fail"
part = "battery"
mode = "stuck"
for_s = 0.2
[[events]]
at_s = 2.2
kind = "bump"
"""


class _Unreadable(World):
    """The Mega rover's world, but its IMU reads NaN over a third of its own time (a model
    that went wrong): readings the link drops and counts."""

    def step(self, until_us: int, act: Actuation, read: bool = True) -> Frame:
        frame = super().step(until_us, act, read)
        if read and frame.t_us // 7000 % 3 == 0:
            frame.imus["imu"] = ImuReading((math.nan, 0.0, 9.8), (0.0, 0.0, 0.0), 20.0)
        return frame


def power_link() -> WorldLink:
    return WorldLink(_Unreadable(parse(POWER, "room.toml"), MEGA, 0, seed=3), MEGA)


def commanded(rng: random.Random, reads: list[tuple[str, tuple[int, ...]]]) -> list[int]:
    """The actuators' reads (as worldfeed.py gives them): motors at a duty in a mode, the
    servo's pulse or limp, the stepper's target and whether it is on."""
    pick = {
        "motor": lambda: rng.choice([0, 1, 1, 2]) * 100000 + 50000 + rng.choice([-9000, 0, 10000]),
        "servo": lambda: rng.choice([-1, 900, 2100]),
        "stepper": lambda: rng.choice([-300, 0, 500]),
        "stepper_on": lambda: rng.choice([0, 1, 1]),
    }
    return [pick[fn]() for fn, _ in reads]


def test_any_part_of_a_batch_made_is_the_ticks_one_at_a_time_and_so_is_the_state() -> None:
    rng = random.Random(8)
    link, one = power_link(), power_link()
    now, used, values = 0, 0, commanded(rng, link.reads)
    made: list[tuple[list[int], Tick]] = []  # (the reads, the tick) of each tick the runtime made
    for _ in range(600):
        batch = link.ahead(now, used, values)
        used = min(len(batch), rng.choice([1, 1, 1, 2, 3, 5, 9, 99, 99]))
        made += [(values, tick) for tick in batch[:used]]
        now = batch[used][0] if used < len(batch) else link.due_us()
        now += rng.choice([0, 0, 0, 1, 2500, 9999, 10_000, 30_000])  # (on time, or late)
        values = commanded(rng, link.reads) if rng.random() < 0.6 else values
    made += [(values, tick) for tick in link.ahead(now, used, values)]  # (the last made whole)
    for k, (values, (t, calls, edges)) in enumerate(made):
        assert one.tick(t, values) == (calls, edges), (k, t)
    volts = [args for _v, (_t, calls, _e) in made for fn, args in calls if fn == "volts"]
    assert len(made) > 800 and len(set(volts)) > 100
    # (the world where its ticks one at a time left it, and the link's counts)
    assert link.world.state() == one.world.state()
    counts = ("readings_dropped", "skips", "skipped_s")
    assert [link.state()[k] for k in counts] == [one.state()[k] for k in counts]
    assert link.state()["readings_dropped"] > 100


SIDES = ("motor_l", "motor_r")


def acting(rng: random.Random) -> Actuation:
    """The Mega rover's actuators (by name, as a link reads them into the world) commanded."""
    modes = ["drive", "drive", "brake", "coast"]
    motor = {n: (rng.choice([-0.9, 0.0, 0.6, 1.0]), rng.choice(modes)) for n in SIDES}
    servo = {"servo": rng.choice([None, 900.0, 2100.0])}
    return Actuation(motor, servo, {"mast": (rng.choice([-300, 0, 500]), rng.random() < 0.7)})


def _run(world: World, t: int, acts: list[Actuation]) -> tuple[list[Frame], int]:
    frames = []
    for act in acts:
        t += 10_000
        frames.append(world.step(t, act))
    return frames, t


def test_a_world_restored_is_in_every_part_the_world_it_was() -> None:
    """World.restore: the world as at its snapshot, every part (the body, the random streams,
    the pack's charge, the motors' current, the rangers' last casts, the events under way),
    and again: run on from there under the same actuators, the same frames to the bit."""
    world = World(parse(POWER, "room.toml"), MEGA, 0, seed=3)
    rng, t = random.Random(2), 0
    for _ in range(60):
        acts = [acting(rng) for _ in range(rng.randint(1, 12))]
        snap = world.snapshot()
        first, end = _run(world, t, acts)
        for _again in range(2):
            world.restore(snap)
            assert world.snapshot() == snap
            assert _run(world, t, acts) == (first, end)
        t = end
    assert world.state()["charge"] < 0.89 and world.state()["t_s"] > 2.3  # (every event came)
