"""The world's ticks to the bit, against hashes recorded before its cost was cut (issue 47.6):
the feed calls and edges the world link hands a runtime, tick after tick, for the rover and the
AVR's rover (servo, battery) at rest, driving into the wall, and through a busy script (motors
driven, braked and coasting at changing duties, one wheel slower, the mast and the servo
turning) with the world file's block, slip, fail, bump and tilt events, pushes by hand, two
seeds and ticks a little and a whole tick late.  A change that moves any reading by as much as
its feed's rounding shows here; the same hashes before and after a cost cut say it moved none.
(They hold the host's libm: recorded and checked on the same machine as the suite.)"""

from __future__ import annotations

import hashlib
import random
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from missing_link.deploy.boardfile import load_board_file
from missing_link.virtual.worldlink import WorldLink
from missing_link.world.world import World
from missing_link.world.worldfile import parse


def _board(name: str) -> dict[str, Any]:
    return load_board_file(
        Path(__file__).resolve().parent.parent / "examples" / "boards" / name
    ).board


ROVER, MEGA = _board("rover.py"), _board("rover-mega.py")
NEAR_WALL = "[start]\nx_m = 3.88\n"
EVENTS = """
[start]
x_m = 3.0
[parts.sonar]
on = "{on}"
[parts.imu]
x_m = 0.05
z_m = 0.03
yaw_deg = 90
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
at_s = 2.2
kind = "fail"
part = "sonar"
for_s = 0.3
[[events]]
at_s = 2.5
kind = "bump"
[[events]]
at_s = 12.0
kind = "slip"
part = "motor_r"
fraction = 0.3
[[events]]
at_s = 14.0
kind = "tilt"
roll_deg = 10
pitch_deg = -5
over_s = 0.5
"""
PUSHES: dict[int, tuple[str, dict[str, Any]]] = {
    40: ("push", {"dx_m": 0.1}), 90: ("turn", {"deg": 30}), 91: ("tilt", {"roll_deg": 5}),
    300: ("place", {"x_m": 0.0, "y_m": 1.0}), 1200: ("bump", {"dx_m": -0.05}),
}  # fmt: skip
Commands = Callable[[int], dict[str, int]]


def _motor(duty: float, mode: int = 1) -> int:
    return mode * 100000 + 50000 + round(duty * 10000)


def _rest(k: int) -> dict[str, int]:
    return {"motor": _motor(0.0, 0), "servo": -1}


def _drive(k: int) -> dict[str, int]:
    return {"motor": _motor(0.5), "servo": 1500, "stepper_on": 1}


def _busy(k: int) -> dict[str, int]:
    """Six phases of 1.5 s: drive, back, brake, full ahead, coast (the servo limp, the mast
    let go in the one before), back slowly; the right wheel slower in two."""
    phase = (k // 150) % 6
    duty, mode = ((0.5, 1), (-0.8, 1), (0.3, 2), (1.0, 1), (0.0, 0), (-0.2, 1))[phase]
    right = duty * 0.6 if phase in (0, 2) else duty
    return {"motor": _motor(duty, mode), "motor_r": _motor(right, mode),
            "servo": 900 + (k // 40) % 5 * 300 if phase != 4 else -1,
            "stepper": (k // 50) * 200 % 3200, "stepper_on": int(phase != 3)}  # fmt: skip


def _hash(text: str, board: dict[str, Any], seed: int, n: int, late: bool, cmds: Commands,
          pushes: bool = False) -> str:  # fmt: skip
    link = WorldLink(World(parse(text, "room.toml"), board, 0, seed=seed), board)
    right = link.index.get("motor_r")
    rng, h, now = random.Random(seed), hashlib.sha256(), 0
    for k in range(n):
        full = cmds(k)
        values = [full.get("motor_r", full["motor"]) if (fn, a[0]) == ("motor", right)
                  else full.get(fn, 0) for fn, a in link.reads]  # fmt: skip
        if pushes and k in PUSHES:
            link.push(PUSHES[k][0], PUSHES[k][1])
        late_us = rng.choice([0, 0, 0, 100, 1500, 3000, 12000]) if late else 0
        now = max(now, link.due_us()) + late_us
        h.update(repr(link.tick(now, values)).encode())
    return h.hexdigest()[:16]


Case = tuple[str, dict[str, Any], int, int, bool, Commands, bool]
# fmt: off
CASES: dict[str, Case] = {
    "rover at rest, late": ("", ROVER, 1, 600, True, _rest, False),
    "rover driving into its wall": (NEAR_WALL, ROVER, 0, 800, False, _drive, False),
    "rover, events, pushes, late": (EVENTS.format(on="mast"), ROVER, 3, 1800, True, _busy, True),
    "rover, events, seed 7": (EVENTS.format(on="mast"), ROVER, 7, 600, False, _busy, True),
    "AVR rover, events, late": (EVENTS.format(on="servo"), MEGA, 4, 1500, True, _busy, True),
}
#: sha256 of each case's ticks (its first 16 hex digits), recorded on 43d602b
HASHES = {
    "rover at rest, late": "2f825999acdf2e1d",
    "rover driving into its wall": "c2f22c0fde61de2c",
    "rover, events, pushes, late": "eab7f8e37647a4a9",
    "rover, events, seed 7": "14c33342e2ea0f05",
    "AVR rover, events, late": "20125ee90f507544",
}
# fmt: on


@pytest.mark.parametrize("case", list(CASES))
def test_the_worlds_ticks_are_what_they_were(case: str) -> None:
    assert _hash(*CASES[case]) == HASHES[case]
