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
    world.answer("tick 10000 motor 0 0 0 0|")  # (a good one: ticked, the next line posted)
    assert world.ticks == 1 and len(posted) == 2
    with caplog.at_level(logging.ERROR, logger="missing_link.virtual.world_avr"):
        world.answer("tick 20000 error unknown command: motor|")
    assert "stopped after 1 ticks" in caplog.text, caplog.text
    assert "ValueError" in world.state()["stopped"]
    world.answer("tick 30000 motor 0 0 0 0|")  # (stopped: nothing more posted)
    assert world.ticks == 1 and len(posted) == 2


def test_the_rig_refusing_the_tick_line_stops_the_world_said(
    caplog: pytest.LogCaptureFixture,
) -> None:
    world = avr_world([])
    with caplog.at_level(logging.ERROR, logger="missing_link.virtual.world_avr"):
        world.answer("error tick 1e6 motor|")
    assert "refused the world's tick" in world.state()["stopped"], world.state()
    assert "stopped after 0 ticks" in caplog.text


def test_refused_feeds_are_counted_in_the_state() -> None:
    world = avr_world([])
    assert "rig_errors" not in world.state() and "stopped" not in world.state()
    world.answer("tick 10000 motor 0 0 0 0|error a;ok;error b")
    world.answer("tick 20000 motor 0 0 0 0|error c")
    assert world.state()["rig_errors"] == 3 and world.ticks == 2
