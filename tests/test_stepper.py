"""The stepper driver's trapezoid (board/drivers/stepper.py), run on CPython against a board
clock that the test advances, with a loop latency that varies: whatever the commands before, a
move to a position arrives there and comes to rest, and a speed of 0 comes to rest (no step
left pending at a speed that rounding brought near zero: a float residue once left the stepper
crawling, one step per eon).  The AVR C (firmware/avr/src/stepper.c) has the same arithmetic and
is run in simavr by tests/test_avr_rover.py; the MicroPython one by tests/test_rover.py."""

from __future__ import annotations

import random
import struct

from hypothesis import given, settings
from hypothesis import strategies as st

from missing_link.board.drivers.stepper import Stepper


class _Pin:
    OUT = 1

    def __init__(self, *_args: object, **_kw: object) -> None:
        self.edges = 0

    def value(self, v: int | None = None) -> int:
        return 0


class _Machine:
    Pin = _Pin


def _run(s: Stepper, clock: list[int], rng: random.Random, seconds: float) -> None:
    end = clock[0] + int(seconds * 1e6)
    while clock[0] < end:
        due = s.next_due_us()
        if due is None:
            return
        clock[0] = max(clock[0], due)
        s.poll(clock[0])
        clock[0] += rng.randint(20, 3000)  # the board loop's latency


def _send(s: Stepper, mode: str, value: float) -> None:
    s.mode = mode
    assert s.command(struct.pack("<f", value)) == (0, b"")


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    microsteps=st.sampled_from([1, 8, 16]),
    max_speed=st.floats(0.1, 3.0),
    accel=st.floats(0.5, 10.0),
)
def test_moves_arrive_and_stops_stop(
    seed: int, microsteps: int, max_speed: float, accel: float
) -> None:
    rng = random.Random(seed)
    clock = [0]
    s = Stepper(
        _Machine, lambda: clock[0], 1, 2, 3, microsteps=microsteps, max_speed=max_speed, accel=accel
    )
    s.set_cb(lambda _ch, _v, _now: None)
    for _ in range(4):  # whatever came before, cut short or not
        if rng.random() < 0.5:
            _send(s, "position", rng.uniform(-2, 2))
        else:
            _send(s, "velocity", rng.uniform(-max_speed, max_speed))
        _run(s, clock, rng, rng.uniform(0.05, 3))
    _send(s, "velocity", -0.7 * max_speed)
    _run(s, clock, rng, 1.0)
    _send(s, "velocity", 0.0)
    _run(s, clock, rng, 60)
    assert s.next_due_us() is None and s.speed == 0.0
    _send(s, "position", 0.5)
    _run(s, clock, rng, 120)
    assert s.next_due_us() is None and s.speed == 0.0
    assert s.position == round(0.5 * s.per_rev)
