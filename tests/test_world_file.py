"""World files (src/missing_link/world/worldfile.py, robot.py): docs/world.md's complete example
parses and builds the rover's world; every key the reader knows is in the docs' reference and
every key there is one it knows; every mistake is one line naming the file and the key."""

from __future__ import annotations

import math
import re
from dataclasses import fields
from pathlib import Path
from typing import Any

import pytest

from missing_link.deploy.boardfile import load_board_file
from missing_link.errors import ConfigError
from missing_link.world.datasheets import FIGURES
from missing_link.world.spec import Battery, Drive, Site
from missing_link.world.world import Actuation, World
from missing_link.world.worldfile import EVENTS, MOUNT_KEYS, WorldFileError, parse

ROOT = Path(__file__).resolve().parent.parent
DOC = (ROOT / "docs" / "world.md").read_text()
ROVER: dict[str, Any] = load_board_file(ROOT / "examples" / "boards" / "rover.py").board


def example() -> str:
    blocks = re.findall(r"```toml\n(.*?)```", DOC, re.S)
    assert len(blocks) == 1
    return blocks[0]


def test_the_docs_example_builds_the_rovers_world() -> None:
    spec = parse(example(), "world.md")
    assert spec.seed == 7 and len(spec.walls) == 6 and len(spec.events) == 3
    w = World(spec, ROVER, 0)
    assert (w.robot.left_motor, w.robot.right_encoder) == ("motor_l", "wheel_r")
    assert w.robot.parts["sonar"].on == "mast" and w.robot.parts["gps"].z == 0.2
    frame = w.step(10_000, Actuation())
    assert set(frame.ranges) == {"sonar", "tof"} and "imu" in frame.imus


def documented_keys() -> set[str]:
    """Every key the reference table names: `[table] key`, `kind = "..."`: keys, figures."""
    table = DOC.split("## The world file", 1)[1].split("```toml", 1)[0]
    keys: set[str] = set()
    for row in table.splitlines():
        if not row.startswith("| `"):
            continue
        first = row.split("|")[1]
        head = re.match(r" `(\[\[?[\w.]+\]\]?)", first)
        cell = re.sub(r"`\[\[?[\w.]+\]\]?(` | )", "`", first)  # (the table out of the way)
        names = re.findall(r"`(\w+)`", cell)
        where = head.group(1).strip("[]") if head else "events"
        if where == "parts.NAME":
            where = "parts"
        keys |= {f"{where}.{n}" for n in names}
    return keys


def test_the_reference_names_every_key_and_only_those() -> None:
    known = {f"world.{k}" for k in ("seed", "tick_ms", "noise")} | {"room.walls", "body.radius_m"}
    known |= {f"start.{k}" for k in ("x_m", "y_m", "yaw_deg")}
    for table, cls in (("drive", Drive), ("battery", Battery), ("site", Site)):
        known |= {f"{table}.{f.name}" for f in fields(cls)}
    known |= {f"parts.{k}" for k in MOUNT_KEYS}
    known |= {f"parts.{k}" for figs in FIGURES.values() for k in figs}
    known |= {"events.at_s", "events.kind"} | {f"events.{k}" for e in EVENTS.values() for k in e}
    documented = documented_keys()
    assert known - documented == set(), "not in docs/world.md"
    assert documented - known == set(), "docs/world.md names keys the reader does not know"


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("[wrld]\n", "wrld: unknown key"),
        ("[world]\ntick_ms = 0.5\n", "world.tick_ms: 0.5 is out of range (1..100)"),
        ("[world]\nnoise = 1\n", "world.noise: expected true or false"),
        ("[drive]\ntrack_m = -0.1\n", "drive.track_m: -0.1 must be above 0"),
        ("[drive]\nkind = 'tank'\n", "drive.kind: 'tank': differential or none"),
        ("[drive]\nleft_motor = 'sonar'\n", "drive.left_motor: 'sonar' is not a motor"),
        ("[battery]\ncharge = 1.5\n", "battery.charge: 1.5 is out of range"),
        ("[room]\nwalls = [[[0, 0], [0, 0]]]\n", "room.walls[0]: a wall needs two different ends"),
        ("[room]\nwalls = [[0, 0]]\n", "room.walls[0]: expected [[x1, y1], [x2, y2]]"),
        ("[start]\nx_m = 5.0\n", "start: the body (0.12 m round) stands in a wall"),
        ("[parts.wheel]\nx_m = 0\n", "parts.wheel: no such part in the board file"),
        ("[parts.sonar]\nnoise_mg = 1\n", "parts.sonar.noise_mg: not a key of a ranger"),
        ("[parts.sonar]\nnoise_m = -1\n", "parts.sonar.noise_m: -1 must be 0 or more"),
        ("[parts.sonar]\non = 'motor_l'\n", "parts.sonar.on: 'motor_l' is no servo or stepper"),
        ("[parts.imu]\ngyro_bias_dps = [1, 2]\n", "parts.imu.gyro_bias_dps: expected 3 numbers"),
        ("[[events]]\nkind = 'block'\npart = 'sonar'\n", "events[0].at_s: when it happens"),
        ("[[events]]\nat_s = 1\nkind = 'jump'\n", "events[0].kind: 'jump': one of push"),
        ("[[events]]\nat_s = 1\nkind = 'block'\n", "events[0].part: a block needs part"),
        ("[[events]]\nat_s = 1\nkind = 'block'\npart = 'imu'\n", "events[0].part: 'imu': a block"),
        ("[[events]]\nat_s = 1\nkind = 'fail'\npart = 'gps'\nmode = 'x'\n", "events[0].mode"),
        ("[[events]]\nat_s = 1\nkind = 'turn'\ndeg = 'a'\n", "events[0].deg: expected a number"),
        ("[[events]]\nat_s = 1\nkind = 'place'\nx_m = 4.95\ny_m = 0\n", "place: (4.95, 0) is in"),
        ("[[events]]\nat_s = 1\nkind = 'slip'\npart = 'mast'\n", "events[0].part: 'mast'"),
        ("x = [\n", "not TOML"),
    ],
)
def test_a_mistake_is_one_line_naming_the_file_and_the_key(text: str, says: str) -> None:
    with pytest.raises(WorldFileError) as e:
        World(parse(text, "room.toml"), ROVER, 0)
    msg = str(e.value)
    assert msg.startswith("room.toml: ") and says in msg and "\n" not in msg, msg
    assert isinstance(e.value, ConfigError)  # (the CLI's exit 2)


def test_defaults_are_a_10_m_room_facing_east_at_its_centre() -> None:
    w = World(parse("", "x"), ROVER, 0)
    corners = [(-5.0, -5.0), (5.0, -5.0), (5.0, 5.0), (-5.0, 5.0)]
    assert w.walls == [(corners[i], corners[(i + 1) % 4]) for i in range(4)]
    assert (w.body.x, w.body.y, w.body.yaw) == (0.0, 0.0, 0.0)
    assert math.isclose(w.spec.drive.wheel_radius_m, 0.033) and w.spec.noise
