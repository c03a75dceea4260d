"""The AVR world's batches of ticks (world_avr.py, the rig's world.c) put into the rig's parts,
at each tick's time, the lines one tick at a time gives (AvrWorld.tick: the world link ticked at
the same times with the same drives and pushes), to the bit: a rig that makes a batch's ticks at
their simulated times while the drives read as it last answered (those whose time has passed
at once), and answers where they change or at the batch's end, as world.c does; two worlds (one
with a failure, a block and a bump), two seeds, five drive patterns, the world's line reaching
the rig up to 1.5 ms late (now and then later than a tick), pushes by hand between batches.
The real rig: tests/test_world_avr_rig.py, and beside the firmware driven (the last test)."""

from __future__ import annotations

import ast
import random
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from missing_link.virtual import world_avr
from missing_link.virtual.world_avr import RIG_LINE_MAX, AvrWorld
from missing_link.virtual.worldlink import WorldLink
from missing_link.world.world import World
from missing_link.world.worldfile import parse

ROVER = Path(__file__).resolve().parents[1] / "examples" / "boards" / "rover-mega.py"
BOARD: dict[str, Any] = ast.literal_eval(ROVER.read_text().split("BOARD = ", 1)[1])
PLAIN = "[start]\nx_m = 3.0\n"
EVENTFUL = (
    PLAIN
    + """
[[events]]
at_s = 0.4
kind = "block"
part = "sonar"
distance_m = 0.3
for_s = 0.4
[[events]]
at_s = 1.0
kind = "fail"
part = "imu"
mode = "silent"
for_s = 0.5
[[events]]
at_s = 1.8
kind = "bump"
"""
)
PUSHES: dict[int, tuple[str, dict[str, Any]]] = {
    30: ("push", {"dx_m": 0.1}),
    90: ("turn", {"deg": 30}),
}
#: a drive pattern: the motors' duties and the stepper's position at a simulated µs
Pattern = Callable[[int], tuple[float, float, int]]
PATTERNS: dict[str, Pattern] = {
    "still": lambda t: (0.0, 0.0, 0),
    "steady": lambda t: (0.5, 0.5, 0),
    "steps": lambda t: ((0.6, -0.3, 0.0)[t // 300_000 % 3], 0.4, 200 * (t // 700_000)),
    "ramp": lambda t: (min(1.0, t / 2e6), -min(1.0, t / 3e6), 0),  # (a new drive every tick)
    "jitter": lambda t: (0.5 + 0.25 * ((t * 7919) // 41_000 % 2), 0.5, (t // 130_000) % 3),
}


def drives(pattern: Pattern, t: int) -> str:
    """The rig's answers to ``motor;stepper`` (motor.c, stepper.c) at ``t``."""
    left, right, steps = pattern(t)
    motor = " ".join(f"{abs(d):.4f} {int(d < 0)}" for d in (left, right))
    return f"motor {motor};stepper {steps} 1 {abs(steps)} 0"


def avr_world(text: str, seed: int, posted: list[str]) -> AvrWorld:
    link = WorldLink(World(parse(text, "room.toml"), BOARD, 0, seed=seed), BOARD)
    return AvrWorld(link, lambda lines: ["ok"] * len(lines), BOARD["transducers"],
                    post=posted.append)  # fmt: skip


Made = tuple[int, str, list[str], list[tuple[str, dict[str, Any]]]]


def batched(text: str, seed: int, pattern: Pattern, n: int) -> tuple[list[Made], AvrWorld]:
    """The ticks a rig following world.c's rule made, ``n`` of them: (its µs, the drives it
    read, the lines it put into the parts, the pushes before it)."""
    rng = random.Random(seed * 31 + n)
    posted: list[str] = []
    world = avr_world(text, seed, posted)
    world.start()
    made: list[Made] = []
    said, now, answers = "", 0, 0
    pushed: list[tuple[str, dict[str, Any]]] = []
    while len(made) < n:
        _asks, entries = posted.pop().split(" ", 1)[1].split("|", 1)
        batch = [(int(e.split(" ", 1)[0]), e.split(" ", 1)[1:]) for e in entries.split("|")]
        # (the line reaches the rig after the world's work: up to 1.5 ms, now and then later)
        now += rng.choice([0, 200, 700, 1500, 1500, 12_000 if rng.random() < 0.05 else 900])
        k = 0
        if len(batch) > 1:  # (the first made at once)
            made.append((batch[0][0], said, _lines(batch[0]), pushed))
            pushed, k = [], 1
        while True:
            now = max(now, batch[k][0] + rng.randrange(0, 120))  # (the rig's next look)
            if k < len(batch) - 1 and drives(pattern, now) == said:
                made.append((batch[k][0], said, _lines(batch[k]), []))
                k += 1
                continue
            said, answers = drives(pattern, now), answers + 1
            if answers in PUSHES:
                world.push(PUSHES[answers][0], PUSHES[answers][1])
                pushed = [PUSHES[answers]]
            world.answer(f"tick {now} {k} {said}|0")
            break
        assert world.failed is None, world.failed
    return made, world


def _lines(entry: tuple[int, list[str]]) -> list[str]:
    return entry[1][0].split(";") if entry[1] else []


CASES = [(text, seed, name) for text in (PLAIN, EVENTFUL) for seed in (1, 2) for name in PATTERNS]


@pytest.mark.parametrize(("text", "seed", "name"), CASES)
def test_the_batches_lines_are_one_at_a_times(text: str, seed: int, name: str) -> None:
    made, world = batched(text, seed, PATTERNS[name], 300)
    one = avr_world(text, seed, [])
    for t, said, lines, pushes in made:
        for kind, args in pushes:
            one.push(kind, args)
        assert lines == one.tick(t, one.drives(said or "motor 0 0 0 0")), t
    assert world.ticks == len(made) and any(lines for _t, _s, lines, _p in made)
    if name == "steady":  # (the drives hold: whole batches, one answer each)
        assert world.link.batch == 10 and len(made) / world.link.batches > 7
    if name == "ramp":  # (a new drive every tick: every batch asked again at its second)
        assert len(made) / world.link.batches < 1.5


def test_a_batch_too_long_for_the_rig_is_cut_and_asked_again_at_the_cut(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    posted: list[str] = []
    world = avr_world(PLAIN, 1, posted)
    world.start()
    say = drives(PATTERNS["still"], 0)
    world.answer(f"tick 0 0 {say}|0")
    whole = posted[-1]
    entries = whole.split("|")[1:]
    assert len(entries) == world.link.batch + 1 and len(whole) < RIG_LINE_MAX
    cut = avr_world(PLAIN, 1, posted)
    cut.start()
    monkeypatch.setattr(world_avr, "RIG_LINE_MAX", len(whole) // 2)
    cut.answer(f"tick 0 0 {say}|0")
    short = posted[-1]
    assert len(short) <= len(whole) // 2 and short.startswith(whole[: len(short) // 2])
    n = len(short.split("|")) - 2  # (the ticks in it; its end the first not sent)
    assert 0 < n < world.link.batch and short.split("|")[-1] == entries[n].split(" ")[0]
    cut.answer(f"tick {int(entries[n].split(' ')[0]) + 50} {n} {say}|0")  # (all made)
    world.answer(f"tick {int(entries[-1]) + 50} {world.link.batch} {say}|0")
    assert cut.ticks == n and world.ticks == world.link.batch
