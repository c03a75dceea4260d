"""docs/ros.md's ros2_control example, as written (issue 45.6): its ``[joints]`` table with the
rover's own board file (examples/boards/rover.py, on the MicroPython firmware under node, its
parts simulated) and nothing else.  The wheel's encoder declares its counts per turn in the
board file, so ``/joint_states`` carries the left wheel in radians out of the box, and the
joints it names are the URDF block's (the mast's a command away: a stepper reports when it moves).
Before, the rover's wheels published counts only."""

from __future__ import annotations

import math
import re
import time
import tomllib
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import pytest
from rosbags.typesys import Stores, get_typestore

from missing_link.daemon import Daemon
from missing_link.daemon.config import parse_config
from missing_link.topics import Update

from .helpers import FirmwareSim, wait_for

pytestmark = [pytest.mark.slow, pytest.mark.micropython]

ROOT = Path(__file__).resolve().parent.parent
ROVER = ROOT / "examples" / "boards" / "rover.py"
STORE = get_typestore(Stores.ROS2_JAZZY)


def docs_blocks() -> tuple[str, list[str]]:
    """(the [joints] TOML, the URDF's joint names) of docs/ros.md's ros2_control section."""
    text = (ROOT / "docs" / "ros.md").read_text()
    section = text[text.index("### ros2_control without C++") :]
    toml = re.search(r"```toml\n(.*?)```", section, re.S)
    xml = re.search(r"```xml\n(.*?)```", section, re.S)
    assert toml is not None and xml is not None
    urdf = ET.fromstring(xml.group(1))
    return toml.group(1), [j.attrib["name"] for j in urdf.iter("joint")]


def test_the_docs_joints_table_and_urdf_name_the_same_joints() -> None:
    toml, urdf = docs_blocks()
    assert sorted(tomllib.loads(toml)["joints"]) == sorted(
        [*urdf, "state_topic", "command_topic", "command_timeout"]
    )


def test_the_docs_example_publishes_the_urdfs_joints_in_radians() -> None:
    toml, urdf = docs_blocks()
    sim = FirmwareSim(ROVER)
    try:
        doc = tomllib.loads(f'[[board]]\nurl = "{sim.url}"\ntimeout = 2.0\n' + toml)
        with Daemon(parse_config(doc, "docs/ros.md")) as d:
            assert d.wait_until_up(30), d.status()
            got: list[Update] = []
            d.subscribe("/joint_states", got.append, queue=0)
            assert wait_for(lambda: "left_wheel" in _names(got), 10), _names(got)
            d.bus.send("/joint_commands", {"name": ["mast"], "position": [math.pi / 4]})
            assert wait_for(lambda: _names(got) >= set(urdf), 10), _names(got)  # (it moved)
            for _ in range(36):  # a quarter turn: 360 of the board file's 1440 counts
                sim.ctl("WORLD.encoder_steps(2, 3, 10)")
                time.sleep(0.03)
            quarter = math.pi / 2
            assert wait_for(lambda: _latest(got, "left_wheel") == pytest.approx(quarter), 5), (
                _latest(got, "left_wheel")
            )
    finally:
        sim.close()
    assert _names(got) == set(urdf)  # (nothing but the URDF's joints)


def _msg(u: Update) -> Any:
    return STORE.deserialize_cdr(u.cdr, "sensor_msgs/msg/JointState")


def _names(got: list[Update]) -> set[str]:
    return {n for u in list(got) for n in _msg(u).name}


def _latest(got: list[Update], joint: str) -> float | None:
    for u in reversed(list(got)):
        m = _msg(u)
        if joint in m.name:
            return float(m.position[list(m.name).index(joint)])
    return None
