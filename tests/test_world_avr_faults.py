"""The AVR world's side (virtual/world_avr.py) when the rig's answers go wrong (the adversary's
findings of 2026-11-29): a world that cannot go on stops said, in the log and in its state, and
the rig's refusals of its lines are counted where ``world URL state`` shows them."""

from __future__ import annotations

import ast
import logging
from pathlib import Path

import pytest

from missing_link.virtual.world_avr import AvrWorld
from missing_link.virtual.worldlink import WorldLink
from missing_link.world.world import World
from missing_link.world.worldfile import parse

ROVER = Path(__file__).resolve().parents[1] / "examples" / "boards" / "rover-mega.py"


def avr_world(posted: list[str]) -> AvrWorld:
    board = ast.literal_eval(ROVER.read_text().split("BOARD = ", 1)[1])
    link = WorldLink(World(parse("[start]\nx_m = 3.0\n", "room.toml"), board, 0, seed=1), board)
    return AvrWorld(link, lambda lines: ["ok"] * len(lines), board["transducers"],
                    post=posted.append)  # fmt: skip


def test_a_tick_answer_it_cannot_read_stops_the_world_said(
    caplog: pytest.LogCaptureFixture,
) -> None:
    posted: list[str] = []
    world = avr_world(posted)
    world.start()
    world.answer("tick 0 0 motor 0 0 0 0;stepper 0 1 0 0|0")  # (a good one: the first batch)
    world.answer("tick 100000 10 motor 0 0 0 0;stepper 0 1 0 0|0")  # (all ten made)
    assert world.ticks == 10 and len(posted) == 3
    with caplog.at_level(logging.ERROR, logger="missing_link.virtual.world_avr"):
        world.answer("tick 120000 2 error unknown command: motor|0")
    assert "stopped after 10 ticks" in caplog.text, caplog.text
    assert "ValueError" in world.state()["stopped"]
    world.answer("tick 130000 1 motor 0 0 0 0|0")  # (stopped: nothing more posted)
    assert world.ticks == 10 and len(posted) == 3


def test_a_rig_that_says_it_made_more_ticks_than_it_had_stops_the_world_said() -> None:
    world = avr_world([])
    world.start()
    world.answer("tick 0 0 motor 0 0 0 0|0")
    world.answer("tick 100000 11 motor 0 0 0 0|0")
    assert "made 11 of 10 ticks" in world.state()["stopped"], world.state()
    assert world.ticks == 0


def test_the_rig_refusing_the_tick_line_stops_the_world_said_and_counted(
    caplog: pytest.LogCaptureFixture,
) -> None:
    world = avr_world([])
    with caplog.at_level(logging.ERROR, logger="missing_link.virtual.world_avr"):
        world.answer("error tick: a time that is not digits: tick motor|1e6")
    state = world.state()
    assert "refused the world's tick" in state["stopped"] and state["rig_errors"] == 1, state
    assert "stopped after 0 ticks" in caplog.text


def test_refused_feeds_are_counted_in_the_state_the_first_logged(
    caplog: pytest.LogCaptureFixture,
) -> None:
    world = avr_world([])
    world.start()
    assert "rig_errors" not in world.state() and "stopped" not in world.state()
    with caplog.at_level(logging.WARNING, logger="missing_link.virtual.world_avr"):
        world.answer("tick 0 0 motor 0 0 0 0|2 error unknown command: a")
        world.answer("tick 100000 10 motor 0 0 0 0|1 error unknown command: c")
    assert world.state()["rig_errors"] == 3 and world.ticks == 10
    assert caplog.text.count("refused a line: error unknown command: a") == 1, caplog.text
    assert "command: c" not in caplog.text
