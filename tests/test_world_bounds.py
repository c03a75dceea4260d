"""A world's numbers beyond what its parts hold (issue 43.1, attacking the world): a world file or
a hand's push with a value finite but huge (a place 1e308 m away, a magnetic field of 1e308 uT)
ended the board ("the firmware stopped: OverflowError" where a reading became the feed's
integers); a drive of 1e6 rad/s made billions of encoder edges a tick (the board held for good);
a world file nested too deep was a RecursionError traceback.  Each is refused in one
line naming the key now, or, within the bounds, runs: every feed call is integers."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest

from missing_link.deploy.boardfile import load_board_file
from missing_link.errors import ConfigError
from missing_link.virtual.worldlink import WorldLink
from missing_link.world.sensing import ImuReading
from missing_link.world.world import World
from missing_link.world.worldfile import WorldFileError, parse

ROOT = Path(__file__).resolve().parent.parent
ROVER: dict[str, Any] = load_board_file(ROOT / "examples" / "boards" / "rover.py").board


def run(text: str, pushes: tuple[tuple[str, dict[str, Any]], ...] = (), ticks: int = 50) -> None:
    """The rover's world from ``text`` through its link for ``ticks`` ticks, the motors at full
    duty, each push by hand after the first tick: every call the link makes is integers."""
    link = WorldLink(World(parse(text, "room.toml"), ROVER, 0), ROVER)
    full = {"motor": 100000 + 50000 + 10000, "servo": 1500, "stepper": 0, "stepper_on": 1}
    values = [full[fn] for fn, _ in link.reads]
    now = link.due_us()
    for n in range(ticks):
        if n == 1:
            for kind, args in pushes:
                link.push(kind, args)
        calls, edges = link.tick(now, values)
        for _fn, args in calls:
            assert all(type(a) is int for a in args), args
        assert all(type(t) is int for t, *_ in edges)
        now = link.due_us()


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("[[events]]\nat_s = 1\nkind = 'place'\nx_m = 1e308\ny_m = 0\n", "events[0].x_m: 1e+308"),
        ("[site]\nfield_ut = [1e308, 0, 0]\n", "site.field_ut: 1e+308 is out of range"),
        ("[site]\nlatitude_deg = 91.0\n", "site.latitude_deg: 91 is out of range (-90..90)"),
        ("[site]\nlongitude_deg = 1e300\n", "site.longitude_deg: 1e+300 is out of range"),
        ("[start]\nx_m = -1e300\n", "start.x_m: -1e+300 is out of range (-1e+06..1e+06)"),
        ("[drive]\nspeed_per_duty = 1e308\n", "drive.speed_per_duty: 1e+308"),
        ("[drive]\nspeed_per_duty = 1e6\n", "1e+06 rad/s is 63661977 encoder edges/s"),
        ("[parts.wheel_l]\ncounts_per_rev = 1e6\n", "is 2387324 encoder edges/s; at most 200000"),
        ("[battery]\ncells = 100000000000000000\n", "battery.cells: 100000000000000000: 1..100"),
        ("[parts.imu]\naccel_density_ug = 1e308\n", "parts.imu.accel_density_ug: 1e+308 is out"),
        ("[parts.sonar]\nmax_m = 1e300\n", "parts.sonar.max_m: 1e+300 is out of range"),
        ("[room]\nwalls = " + "[" * 5000 + "]" * 5000 + "\n", "not TOML: nested too deep"),
        ("x = " + "{a = " * 5000 + "1" + "}" * 5000 + "\n", "not TOML: nested too deep"),
    ],
)
def test_a_number_beyond_a_world_is_one_line_naming_its_key(text: str, says: str) -> None:
    with pytest.raises(WorldFileError) as e:
        run(text)
    msg = str(e.value)
    assert msg.startswith("room.toml: ") and says in msg and "\n" not in msg, msg
    assert isinstance(e.value, ConfigError)  # (the CLI's exit 2)


@pytest.mark.parametrize(
    ("kind", "args", "says"),
    [
        ("place", {"x_m": 1e308, "y_m": 1e308}, "place x_m: 1e+308 is out of range"),
        ("push", {"dx_m": 1e300, "over_s": 1.0}, "push dx_m: 1e+300 is out of range"),
        ("turn", {"deg": 1e300, "over_s": 1e-9}, "turn deg: 1e+300 is out of range"),
        ("tilt", {"roll_deg": -1e300}, "tilt roll_deg: -1e+300 is out of range"),
        ("block", {"part": "sonar", "for_s": 1e300}, "block for_s: 1e+300 is out of range"),
    ],
)
def test_a_push_by_hand_beyond_a_world_is_refused_and_the_world_goes_on(
    kind: str, args: dict[str, Any], says: str
) -> None:
    link = WorldLink(World(parse("", "room.toml"), ROVER, 0), ROVER)
    with pytest.raises(WorldFileError, match=says.replace("+", r"\+")):
        link.push(kind, args)
    run("")


def test_the_largest_numbers_a_world_takes_still_feed_integers() -> None:
    far = 1e6 - 1
    run(
        "[drive]\nspeed_per_duty = 870\nwheel_radius_m = 1e6\n"
        "[site]\nfield_ut = [1e6, -1e6, 1e6]\nlatitude_deg = 90\nlongitude_deg = -180\n"
        "[parts.imu]\naccel_density_ug = 1e6\ngyro_density_dps = 1e6\n",
        pushes=(
            ("push", {"dx_m": far, "dy_m": -far, "over_s": 0.0}),
            ("turn", {"deg": far, "over_s": 0.0}),
            ("tilt", {"roll_deg": far, "pitch_deg": -far, "over_s": 0.0}),
            ("place", {"x_m": far, "y_m": -far, "yaw_deg": far}),
        ),
    )


class _Unreadable(World):
    """The rover's world, but its IMU reads NaN and a turn rate beyond any small integer and its
    sonar infinity on every other step (a model that went wrong): the link's own guard."""

    def step(self, until_us: int, act: Any) -> Any:
        frame = super().step(until_us, act)
        if frame.t_us // round(self.spec.tick_ms * 1000) % 2:
            frame.imus["imu"] = ImuReading((math.nan, 0.0, 9.8), (0.0, 0.0, 1e30), 20.0)
            frame.ranges["sonar"] = math.inf
        return frame


def test_a_reading_that_is_no_small_integer_is_not_fed_and_is_counted() -> None:
    world = _Unreadable(parse("", "room.toml"), ROVER, 0)
    link = WorldLink(world, ROVER)
    values = [0 for _ in link.reads]
    fed: list[tuple[str, tuple[int, ...]]] = []
    now = link.due_us()
    for _ in range(10):
        calls, _edges = link.tick(now, values)
        fed += calls
        now = link.due_us()
    imu, sonar = link.index["imu"], link.index["sonar"]
    assert [a for fn, a in fed if fn == "imu" and a[0] == imu]  # (the steps between: fed)
    assert all(abs(v) < 1 << 30 for _fn, args in fed for v in args)
    assert link.state()["readings_dropped"] == 10  # (five steps' IMU and sonar each)
    assert [a for fn, a in fed if fn == "ranger" and a[0] == sonar]


def test_a_board_paused_for_a_minute_finds_its_world_paused_not_a_minute_run_at_once() -> None:
    """A host that stopped the board 60 s (SIGSTOP, a laptop's suspend): the board's clock jumps
    a minute at its next tick.  The world runs at most MAX_CATCHUP_US of it (a minute's run at
    once was 57,210 encoder edges on the rover, all delivered at once), stands still for the
    rest, and says so in its state; its own time (events, pushes) paused with it."""
    from missing_link.virtual.worldlink import MAX_CATCHUP_US

    link = WorldLink(World(parse("", "room.toml"), ROVER, 0), ROVER)
    full = {"motor": 100000 + 50000 + 5000, "servo": 1500, "stepper": 0, "stepper_on": 1}
    values = [full[fn] for fn, _ in link.reads]
    for _ in range(100):  # (a second driving at half duty, ticking on time)
        _calls, edges = link.tick(link.due_us(), values)
    per_tick = len(edges)
    assert per_tick > 0
    before = link.state()
    now = link.due_us() + 60_000_000
    _calls, edges = link.tick(now, values)
    # the stretch the world ran: MAX_CATCHUP_US and the tick ahead, its edges in it
    ran = (MAX_CATCHUP_US + link.tick_us) // link.tick_us
    assert len(edges) <= (ran + 1) * per_tick, len(edges)
    assert all(now - MAX_CATCHUP_US <= t <= now + link.tick_us for t, *_ in edges)
    st = link.state()
    assert st["skips"] == 1 and st["skipped_s"] == pytest.approx(60 - MAX_CATCHUP_US / 1e6)
    assert st["t_s"] == pytest.approx(before["t_s"] + MAX_CATCHUP_US / 1e6 + link.tick_us / 1e6)
    travelled = math.hypot(st["x_m"] - before["x_m"], st["y_m"] - before["y_m"])
    assert travelled <= (ran + 1) * before["speed_m_s"] * link.tick_us / 1e6
    _calls, edges = link.tick(link.due_us(), values)  # (and then on as before)
    assert 0 < len(edges) <= per_tick + 1 and link.state()["skips"] == 1
