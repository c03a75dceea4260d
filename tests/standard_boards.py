"""Board files as virtual boards for the standard-type tests (test_standard_boards.py and the
faces' tests): the rover and the thesis rig of examples/boards, and tests/boards/battery-pico.py,
each with every part simulated from its datasheet, and one daemon configuration for them.

Today a board file runs as our MicroPython firmware under node (``FirmwareSim``: real
MicroPython, simulated devices, ``ctl`` drives the simulated world).  When ``missing-link board
--file BOARDFILE`` lands (issue 35, item 1), ``virtual_board`` is the one line to change."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from .helpers import FirmwareSim

ROOT = Path(__file__).resolve().parent.parent
RIG = ROOT / "examples" / "boards" / "thesis-rig.py"
ROVER = ROOT / "examples" / "boards" / "rover.py"
POWER = ROOT / "tests" / "boards" / "battery-pico.py"
#: the rig's and the rover's encoders: this many counts (edges, x4) per wheel turn
COUNTS_PER_REV = 400


def virtual_board(board_file: Path) -> FirmwareSim:
    """A board file running as a virtual board: ``.url`` to connect, ``.ctl(code)`` to act on
    its simulated parts (WORLD), ``.close()``."""
    return FirmwareSim(board_file)


@pytest.fixture(scope="module")
def boards() -> Iterator[dict[str, FirmwareSim]]:
    """The three boards (rig, rover, power), booted once for a module's tests."""
    sims: dict[str, FirmwareSim] = {}
    try:
        for name, path in (("rig", RIG), ("rover", ROVER), ("power", POWER)):
            sims[name] = virtual_board(path)
        yield sims
    finally:
        for s in sims.values():
            s.close()


def daemon_toml(rig: str, rover: str, power: str, *, publishers: str = '["bus"]') -> str:
    """The daemon's configuration for the three boards: encoders' counts per turn, a frame id,
    one transducer without standard types and one without its thesis topic, and joints."""
    return f"""
[daemon]
publishers = {publishers}

[[board]]
url = "{rig}"
timeout = 2.0
[[board]]
url = "{rover}"
timeout = 2.0
[[board]]
url = "{power}"
timeout = 2.0

[boards.rig.ros.wheel]
counts_per_rev = {COUNTS_PER_REV}
[boards.rig.ros.sonar]
standard = false
[boards.rover.ros.wheel_l]
counts_per_rev = {COUNTS_PER_REV}
frame_id = "left_wheel_link"
[boards.rover.ros.wheel_r]
counts_per_rev = {COUNTS_PER_REV}
[boards.power.ros.bumper]
thesis = false

[joints]
command_timeout = 0.5
[joints.left_wheel]
state = "rover/wheel_l"
command = "rover/motor_l"
[joints.mast]
state = "rover/mast"
command = "rover/mast"
[joints.pan]
state = "rig/servo"
command = "rig/servo"
"""
