"""The world beside a CPython firmware (world_cpython.py) and the batches' length
(worldlink.py): a firmware asleep over several of the world's ticks gets them at its next turn,
each at its own time, and the encoders' edges of that time delivered in time order with the
board's clock held at each; a runtime that comes late under the same actuators keeps its batch
(the ticks it makes are those of a link ticked one at a time at their times); one whose
actuators change at every tick computes barely more ticks than it makes."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from missing_link.deploy.boardfile import load_board_file
from missing_link.virtual.world import machine, worldfeed
from missing_link.virtual.world.parts import populate
from missing_link.virtual.world_cpython import BoardClock, CPythonWorld
from missing_link.virtual.worldlink import Ahead, Call, Edge, WorldLink
from missing_link.world.world import World
from missing_link.world.worldfile import parse

ROOT = Path(__file__).resolve().parent.parent
ROVER: dict[str, Any] = load_board_file(ROOT / "examples" / "boards" / "rover.py").board
ROOM = parse("[start]\nx_m = 3.0\n", "room.toml")


class Counting(WorldLink):
    """A world link that counts the ticks it computes (a batch's, and those made again)."""

    computed = 0

    def _tick(self, now_us: int, act: Any) -> tuple[list[Call], list[Edge]]:
        self.computed += 1
        return super()._tick(now_us, act)


def link(cls: type[WorldLink] = WorldLink) -> WorldLink:
    return cls(World(ROOM, ROVER, 0, seed=3), ROVER)


def driving(duty: int) -> list[int]:
    """The rover's reads, its motors at ``duty`` (1/10000) forward."""
    code = {"motor": 150000 + duty, "servo": 1500, "stepper": 0, "stepper_on": 1}
    return [code[fn] for fn, _ in link().reads]


def test_a_late_runtime_keeps_its_batch_and_gets_each_tick_at_its_time() -> None:
    world, one = link(), link()
    runtime, values, now = Ahead(world), driving(5000), 0
    made = []
    for late in [0, 35_000, 3_000, 120_000, 10_000, 2_000, 250_000, 15_000] * 4:
        now = max(now, runtime.due_us()) + late
        while runtime.due_us() <= now:  # (as CPythonWorld.pump: each due tick, at its time)
            made.append(runtime.tick(now, values))
    assert [t for t, _c, _e in made] == [k * world.tick_us for k in range(len(made))]
    assert made == [(t, *one.tick(t, values)) for t, _c, _e in made]
    assert world.rewound == 0 and world.batches <= len(made) // world.most + 1
    assert sum(len(e) for _t, _c, e in made) > 1000


def test_actuators_changing_at_every_tick_cost_barely_more_than_their_ticks() -> None:
    world, one = link(Counting), link()
    assert isinstance(world, Counting)
    runtime = Ahead(world)
    reads = [driving(1000 + 10 * k) for k in range(200)] + [driving(4000)] * 200  # (then held)
    made = [runtime.tick(runtime.due_us(), values) for values in reads]
    assert made == [(t, *one.tick(t, v)) for (t, _c, _e), v in zip(made, reads, strict=True)]
    # (each batch after the first cut at once: one tick long, now and then two; then grown)
    assert world.computed < 1.6 * len(made)
    assert world.batch == world.most


def test_a_batch_none_of_which_was_made_is_gone_back_over_from_before_its_first() -> None:
    world, one = link(), link()  # (made_first unset: AVR's rig may make none of a batch)
    b = driving(2000)
    world.ahead(0, 0, driving(5000))
    made = world.ahead(0, 0, b)  # (the drives changed before its first tick)
    made += world.ahead(world.due_us(), 1, b)  # (each one tick long: the last was used so)
    grown = world.ahead(world.due_us(), 1, b)  # (two used whole: two ticks)
    made += grown[:1] + world.ahead(grown[1][0], 1, b)  # (only its first made)
    assert made == [(t, *one.tick(t, b)) for t, _c, _e in made]
    assert [len(made), len(grown), world.rewound] == [4, 2, 2]


@pytest.fixture
def simulator() -> Iterator[None]:
    """The simulated world of one board file (one per process), emptied after the test."""
    assert not machine.WORLD.devices, "the simulated world is taken"
    yield
    machine.WORLD.__init__()  # type: ignore[misc]  # (in place: the world's modules hold it)


class Clock(BoardClock):
    """The board's clock, set by the test (held at an edge's time as the board's is)."""

    def __init__(self, now: int) -> None:
        super().__init__()
        self.now = now

    def __call__(self) -> int:
        return self.held if self.held is not None else self.now


@pytest.mark.usefixtures("simulator")
def test_a_firmware_asleep_over_ticks_gets_them_and_its_edges_in_time_order() -> None:
    populate(ROVER)
    clock = Clock(0)
    world = CPythonWorld(link(), clock)
    one = link()
    for pin in (12, 18):  # (the motors' IN1 at half duty, IN2 low: both forward)
        machine.PWM(machine.Pin(pin), freq=20000, duty_ns=25000)
    seen: list[tuple[int, Any]] = []
    a, b = one.pins["wheel_l"]
    for pin in (a, b):  # (a handler on both phases: it sees each edge of the left wheel)
        machine.Pin(pin).irq(lambda p: seen.append((clock(), p)))
    values = [getattr(worldfeed, fn)(*args) for fn, args in world.link.reads]
    world.pump()  # (the first tick, at 0)
    for sleep in (47_000, 3_000, 160_000, 9_999, 1):
        clock.now += sleep
        world.pump()  # (the firmware's next turn: its sleeps are its own)
        assert world.ahead.due_us() > clock.now >= max([t for t, *_ in seen], default=0)
        assert all(t > clock.now for t, *_ in world.pending)
    assert world.ticks == clock.now // one.tick_us + 1  # (each on time, 0 to now)
    assert world.link.rewound == 0 and world.link.batches < 6  # (each used whole)
    want = [(t, a_, b_, d) for k in range(world.ticks)
            for t, a_, b_, d in one.tick(k * one.tick_us, values)[1] if a_ == a]  # fmt: skip
    assert [t for t, _lv in seen] == [t for t, *_ in want if t <= clock.now]
    assert len(seen) > 50 and clock.held is None
