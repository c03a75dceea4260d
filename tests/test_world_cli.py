"""The world from the command line (docs/world.md, docs/cli.md): ``board --file --world FILE``
takes a world file or says in one line what is wrong with it (exit 2); ``--world-control``
opens the world's endpoint on loopback or a unix socket (0600) only; ``missing-link world URL
VERB`` pushes the robot by hand and prints its state, one line and exit 2 for a push the world
refuses, exit 1 when no world answers; a push shows in what the board's sensors report, on
CPython and under MicroPython (its world beside node: virtual/world_mpy.py)."""

from __future__ import annotations

import json
import math
import os
import stat
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config
from missing_link.topics import Update

from .helpers import ML, ml, wait_for

ROOT = Path(__file__).resolve().parent.parent
ROVER = ROOT / "examples" / "boards" / "rover.py"
pytestmark = pytest.mark.slow
RUNTIMES = ("cpython", pytest.param("micropython", marks=pytest.mark.micropython))


class Rover:
    """The rover as a virtual board with a world and its control on a unix socket."""

    def __init__(self, tmp: Path, *extra: str, file: Path = ROVER) -> None:
        self.control = tmp / "world.sock"
        cmd = [*ML, "board", "--file", str(file), "--listen", "tcp://127.0.0.1:0",
               "--world-control", f"unix://{self.control}", *extra]  # fmt: skip
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        assert self.proc.stdout is not None
        first, second = self.proc.stdout.readline(), self.proc.stdout.readline()
        assert first.startswith("LISTENING ") and second.startswith("WORLD "), (first, second)
        self.url, self.world = first.split()[1], second.split()[1]

    def state(self) -> dict[str, Any]:
        r = ml("world", self.world, "--json", "state")
        assert r.returncode == 0, r.stderr
        out: dict[str, Any] = json.loads(r.stdout)
        return out

    def close(self) -> None:
        self.proc.terminate()
        self.proc.communicate(timeout=10)


@pytest.fixture
def rover(tmp_path: Path) -> Iterator[Rover]:
    r = Rover(tmp_path)
    try:
        yield r
    finally:
        r.close()
    assert r.proc.returncode == 0


@pytest.fixture(params=RUNTIMES)
def any_rover(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Rover]:
    """The rover on each runtime that has a world."""
    r = Rover(tmp_path, "--runtime", request.param)
    try:
        yield r
    finally:
        r.close()
    assert r.proc.returncode == 0


def test_a_hand_pushes_turns_and_blocks_and_the_sensors_say_so(any_rover: Rover) -> None:
    rover = any_rover
    assert stat.S_IMODE(os.stat(rover.control).st_mode) == 0o600
    with Daemon(Config(boards=[BoardSpec(rover.url, timeout=3.0)])) as d:
        assert d.wait_until_up(30)
        sonar: list[Update] = []
        d.subscribe("/rover/sonar", sonar.append, queue=0)
        assert wait_for(lambda: len(sonar) >= 2, 10)
        assert sonar[-1].values == [None]  # (4.88 m to the wall ahead: beyond its 4 m)
        r = ml("world", rover.world, "push", "1.5", "--over", "0.5")
        assert r.returncode == 0 and r.stdout.startswith("t "), r.stderr
        assert wait_for(lambda: rover.state()["x_m"] > 1.49, 10)
        n = len(sonar)
        assert wait_for(lambda: len(sonar) > n + 2, 10)
        assert sonar[-1].values[0] == pytest.approx(5000 - 1500 - 120, abs=12)  # mm (+-4 sigma)
        assert ml("world", rover.world, "turn", "90").returncode == 0
        assert wait_for(lambda: abs(rover.state()["yaw_deg"] - 90) < 0.01, 10)
        assert ml("world", rover.world, "block", "sonar", "0.3", "--for", "60").returncode == 0
        n = len(sonar)
        assert wait_for(lambda: len(sonar) > n + 2 and sonar[-1].values[0] is not None, 10)
        assert sonar[-1].values[0] == pytest.approx(300, abs=12)
        assert rover.state()["blocked"] == ["sonar"]


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (("block", "nosuch"), "world: block part: 'nosuch': a block takes one of sonar, tof"),
        (("slip", "mast"), "world: slip part: 'mast'"),
        (("place", "4.95", "0"), "place: (4.95, 0) is in a wall"),
        (("tilt", "95", "0"), "argument roll_deg: 95 is over 90 deg"),
    ],
)
def test_a_push_the_world_refuses_is_one_line(
    rover: Rover, args: tuple[str, ...], says: str
) -> None:
    r = ml("world", rover.world, *args)
    assert r.returncode == 2 and says in r.stderr and r.stderr.count("\n") == 1, r.stderr


@pytest.mark.avr
def test_the_avr_rover_drives_in_its_world_and_its_sonar_sees_the_wall(tmp_path: Path) -> None:
    """The AVR rover (rover-mega.py, its right motor and encoder mirrored) in simavr, its world
    beside it (world_avr.py): driven forward, both wheels count forward, the body turns by what
    their difference says and moves by what they rolled, and the HC-SR04 sees the wall where
    the body now is."""
    rover = Rover(tmp_path, "--runtime", "avr", file=ROVER.with_name("rover-mega.py"))
    try:
        assert ml("world", rover.world, "place", "2", "0").returncode == 0
        with Daemon(Config(boards=[BoardSpec(rover.url, timeout=3.0)])) as d:
            assert d.wait_until_up(30)
            got: dict[str, list[Update]] = {}
            d.subscribe("/mega_rover/*", lambda u: got.setdefault(u.topic.name, []).append(u),
                        queue=0)  # fmt: skip
            sonar = got.setdefault("/mega_rover/sonar", [])
            assert wait_for(lambda: len(sonar) >= 3, 10)
            before = rover.state()
            assert sonar[-1].values[0] == pytest.approx(5000 - 2000 - 120, abs=12)  # mm, 4 sigma
            t0 = time.monotonic()
            while time.monotonic() - t0 < 2.0:  # (as a controller does: every 0.2 s)
                for side in ("l", "r"):
                    d.send(f"/mega_rover/motor_{side}/cmd", 0.5)
                time.sleep(0.2)
            for side in ("l", "r"):
                d.send(f"/mega_rover/motor_{side}/cmd", 0.0)
            assert wait_for(lambda: rover.state()["speed_m_s"] == 0.0, 10)
            time.sleep(0.5)  # (the wheels' last samples)
            left, right = (got[f"/mega_rover/wheel_{s}"][-1].values[0] for s in ("l", "r"))
            after = rover.state()
            # turned back to face the wall square on by hand: it sees it where the body is
            assert ml("world", rover.world, "turn", f"{-after['yaw_deg']:.4f}").returncode == 0
            assert wait_for(lambda: abs(rover.state()["yaw_deg"]) < 0.01, 10)
            n = len(sonar)
            assert wait_for(lambda: len(sonar) > n + 2, 10)
            x = rover.state()["x_m"]
            assert sonar[-1].values[0] == pytest.approx(5000 - 1000 * x - 120, abs=12)
    finally:
        rover.close()
    assert rover.proc.returncode == 0
    # (each motor's command goes on its own, with its ramp: on a busy machine they reach the AVR
    # tens of ms apart and one wheel turns longer than the other: the body turns)
    assert left > 300 and right > 300, (left, right)
    per_count = 2 * math.pi * 0.033 / 400  # (m: 400 counts a turn, r 33 mm; track 0.16 m)
    turned = (right - left) * per_count / 0.16  # (counter-clockwise: the right one further)
    assert math.radians(after["yaw_deg"] - before["yaw_deg"]) == pytest.approx(turned, abs=0.01)
    rolled = (left + right) / 2 * per_count  # (the path; its chord is shorter when it turned)
    moved = math.hypot(after["x_m"] - before["x_m"], after["y_m"] - before["y_m"])
    assert rolled * math.cos(turned / 2) - 0.01 <= moved <= rolled + 0.01, (left, right, after)


def test_no_world_there_is_one_line_exit_1(tmp_path: Path) -> None:
    r = ml("world", f"unix://{tmp_path}/none.sock", "state")
    assert r.returncode == 1 and "no world answers there" in r.stderr, r.stderr
    assert r.stderr.count("\n") == 1


@pytest.mark.parametrize(
    ("text", "extra", "says"),
    [
        ("[drive]\ntrack_m = -1\n", (), "room.toml: drive.track_m: -1 must be above 0"),
        ("[parts.lidar]\nx_m = 0\n", (), "room.toml: parts.lidar: no such part in the board file"),
        ("", ("--world-control", "tcp://0.0.0.0:0"), "on 127.0.0.1 or a unix socket only"),
    ],
)
def test_a_bad_world_is_one_line_exit_2(
    tmp_path: Path, text: str, extra: tuple[str, ...], says: str
) -> None:
    world = tmp_path / "room.toml"
    world.write_text(text)
    r = ml("board", "--file", str(ROVER), "--listen", "tcp://127.0.0.1:0", "--world", str(world),
           *extra, timeout=60)  # fmt: skip
    assert r.returncode == 2 and says in r.stderr and r.stderr.count("\n") == 1, r.stderr


def test_no_world_file_there_and_no_world_with_a_control() -> None:
    r = ml("board", "--file", str(ROVER), "--listen", "tcp://127.0.0.1:0", "--world", "gone.toml")
    assert r.returncode == 2 and "--world gone.toml: cannot read it" in r.stderr, r.stderr
    r = ml("board", "--file", str(ROVER), "--listen", "tcp://127.0.0.1:0", "--world", "none",
           "--world-control", "tcp://127.0.0.1:0")  # fmt: skip
    assert r.returncode == 2 and "needs a world" in r.stderr, r.stderr
