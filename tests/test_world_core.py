"""The world's pure core (src/missing_link/world/): the kinematics as properties (a straight drive
in an empty room: odometry is the pose; a turn in place keeps the position), REP-103's signs,
what a ranger, the IMU, the compass and the GPS read from the body's state, determinism from a
seed, and events; the noise figures against golden values worked out from the datasheets here,
by hand, not from the code's tables."""

from __future__ import annotations

import itertools
import math
import statistics
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from missing_link.deploy.boardfile import load_board_file
from missing_link.world.spec import Drive, WorldSpec
from missing_link.world.world import Actuation, Frame, World
from missing_link.world.worldfile import parse

ROOT = Path(__file__).resolve().parent.parent
ROVER: dict[str, Any] = load_board_file(ROOT / "examples" / "boards" / "rover.py").board
G = 9.80665
TICK = 10_000
#: a room so large nothing is near: the kinematics alone
OPEN = ((-1000.0, -1000.0), (1000.0, -1000.0))


def world(text: str = "", board: dict[str, Any] | None = None, seed: int = 0) -> World:
    return World(parse(text, "test.toml"), board or ROVER, 0, seed=seed)


def drive(w: World, left: float, right: float, seconds: float, mode: str = "drive") -> list[Frame]:
    act = Actuation(motors={"motor_l": (left, mode), "motor_r": (right, mode)})
    frames = []
    for _ in range(round(seconds * 1e6 / TICK)):
        frames.append(w.step(w.t_us + TICK, act))
    return frames


def counts(frames: list[Frame], encoder: str) -> int:
    return sum(d for f in frames for _t, d in f.edges[encoder])


@settings(max_examples=25, deadline=None)
@given(duty=st.floats(-1, 1).filter(lambda d: abs(d) > 0.01), seconds=st.floats(0.05, 1.5))
def test_a_straight_drive_in_an_empty_room_odometry_is_the_pose(
    duty: float, seconds: float
) -> None:
    w = world("[room]\nwalls = [[[-1000, -1000], [1000, -1000]]]\n")
    frames = drive(w, duty, duty, seconds)
    per_count = 2 * math.pi * 0.033 / 400
    left, right = counts(frames, "wheel_l"), counts(frames, "wheel_r")
    assert left == right
    travelled = math.hypot(w.body.x, w.body.y)
    assert abs(left * per_count - math.copysign(travelled, duty)) <= per_count
    assert w.body.y == pytest.approx(0.0, abs=1e-12) and w.body.yaw == 0.0


def test_a_mirrored_motor_and_encoder_drive_straight_as_their_firmware_flips_them() -> None:
    """A right motor mounted mirrored ("invert": its firmware drives its bridge backward for
    forward) turns its wheel forward, and its encoder ("reverse") counts backward, as the
    AVR rover's (examples/boards/rover-mega.py): the body rolls straight ahead."""
    mega: dict[str, Any] = load_board_file(ROOT / "examples" / "boards" / "rover-mega.py").board
    w = world("[room]\nwalls = [[[-1000, -1000], [1000, -1000]]]\n", mega)
    frames = drive(w, 0.5, -0.5, 1.0)  # (the bridges' pins: the right one backward)
    assert w.body.x > 0.1 and w.body.yaw == pytest.approx(0.0, abs=1e-12)
    assert counts(frames, "wheel_l") == -counts(frames, "wheel_r") > 0


@settings(max_examples=25, deadline=None)
@given(duty=st.floats(0.05, 1), seconds=st.floats(0.05, 1.5), yaw=st.floats(-3, 3))
def test_a_turn_in_place_keeps_the_position(duty: float, seconds: float, yaw: float) -> None:
    w = world(f"[start]\nx_m = 1.0\ny_m = -2.0\nyaw_deg = {math.degrees(yaw)}\n")
    frames = drive(w, -duty, duty, seconds)
    assert (w.body.x, w.body.y) == (pytest.approx(1.0, abs=1e-12), pytest.approx(-2.0, abs=1e-12))
    right = counts(frames, "wheel_r")
    assert counts(frames, "wheel_l") == -right
    turned = 2 * (2 * math.pi * right / 400) * 0.033 / 0.16  # (both wheels, opposite)
    assert w.body.yaw - yaw == pytest.approx(turned, abs=2 * 2 * math.pi / 400 * 0.033 / 0.16)
    assert w.body.yaw > yaw  # right wheel forward: counter-clockwise, REP-103's positive yaw


def test_turning_left_the_gyro_reads_positive_z_and_the_compass_turns_with_it() -> None:
    w = world("[world]\nnoise = false\n")
    frames = drive(w, -0.5, 0.5, 2.0)
    rates = [f.imus["imu"].gyro[2] for f in frames]
    assert all(r >= 0 for r in rates) and max(rates) > 1.0
    integral = sum((a + b) / 2 * TICK / 1e6 for a, b in itertools.pairwise(rates))  # (trapezoids)
    headings = [math.atan2(-f.fields["compass"][1], f.fields["compass"][0]) for f in frames]
    change = sum(math.remainder(b - a, 2 * math.pi) for a, b in itertools.pairwise(headings))
    assert change == pytest.approx(integral, abs=math.radians(0.5))
    # (the heading the compass gives turns the way the body does: the field turns the other way)


def test_at_rest_the_accelerometer_reads_g_up_and_a_tilt_turns_it() -> None:
    w = world("[world]\nnoise = false\n", ROVER)
    f = drive(w, 0, 0, 0.1)[-1]
    assert f.imus["imu"].accel == (0.0, 0.0, pytest.approx(G))
    w.command("tilt", {"pitch_deg": 30.0, "over_s": 0.2})
    f = drive(w, 0, 0, 1.0)[-1]
    ax, ay, az = f.imus["imu"].accel
    # nose down by 30 degrees (REP-103: a positive pitch): "up" leans back, towards -x
    assert ax == pytest.approx(-G * math.sin(math.radians(30)))
    assert (ay, az) == (pytest.approx(0.0, abs=1e-9), pytest.approx(G * math.cos(math.radians(30))))


def test_the_forward_ranger_sees_the_wall_come_nearer_by_what_the_wheels_rolled() -> None:
    w = world("[world]\nnoise = false\n")
    start = w.step(TICK, Actuation()).ranges
    assert start == {"sonar": None, "tof": None}  # (4.88 m: beyond both)
    frames = drive(w, 0.8, 0.8, 16.0)
    # from when the wall comes in reach (4 m) until the body's edge is 5 cm from it
    seen = [i for i, f in enumerate(frames) if (f.ranges["sonar"] or 0) > 0.05]
    first, last = seen[0], seen[-1]
    rolled = counts(frames[first:last], "wheel_l") * 2 * math.pi * 0.033 / 400
    fell = frames[first].ranges["sonar"] - frames[last].ranges["sonar"]  # type: ignore[operator]
    assert fell == pytest.approx(rolled, abs=2 * 2 * math.pi * 0.033 / 400)  # (2 counts)
    # it got to the wall: stopped there, its front edge touching, once
    assert w.body.bumps == 1 and w.body.x == pytest.approx(5 - 0.12, abs=0.01)
    assert frames[-1].ranges["sonar"] == pytest.approx(0.0, abs=0.01)


def test_the_same_seed_gives_the_same_samples_and_another_seed_others() -> None:
    board = ROVER
    runs = []
    for seed in (7, 7, 8):
        w = world("", board, seed=seed)
        frames = drive(w, 0.3, 0.5, 1.0) + drive(w, -0.2, 0.1, 0.5)
        runs.append([(f.imus, f.fields, f.fixes, f.ranges, f.edges, f.volts) for f in frames])
    assert runs[0] == runs[1]
    assert runs[0] != runs[2]


def sample_std(values: list[float]) -> float:
    return statistics.pstdev(values)


def test_noise_matches_the_datasheets() -> None:
    board = ROVER
    w = world("", board, seed=3)
    frames = drive(w, 0, 0, 40.0)  # 4000 samples each
    imu = [f.imus["imu"] for f in frames]
    # MPU-6050 rev 3.4: 400 ug/sqrt(Hz) and 0.005 deg/s/sqrt(Hz); DLPF 3: 44 Hz (accel), 42 Hz
    assert sample_std([i.accel[0] for i in imu]) == pytest.approx(400e-6 * G * math.sqrt(44),
                                                                   rel=0.05)  # fmt: skip
    assert sample_std([i.gyro[2] for i in imu]) == pytest.approx(
        math.radians(0.005) * math.sqrt(42), rel=0.05
    )
    # QMC5883L: 2 mG rms
    assert sample_std([f.fields["compass"][1] for f in frames]) == pytest.approx(0.002, rel=0.05)


def test_rangers_noise_from_their_datasheets() -> None:
    near = "[start]\nx_m = 3.5\n"  # the front edge 1.38 m from the wall at x = 5
    w = world(near, seed=5)
    frames = drive(w, 0, 0, 40.0)
    sonar = [f.ranges["sonar"] for f in frames]
    tof = [f.ranges["tof"] for f in frames]
    assert statistics.fmean(sonar) == pytest.approx(1.38, abs=0.001)  # type: ignore[arg-type]
    assert sample_std(sonar) == pytest.approx(0.003, rel=0.05)  # type: ignore[arg-type]  # HC-SR04
    assert sample_std(tof) == pytest.approx(0.03 * 1.38, rel=0.05)  # type: ignore[arg-type]  # 3 %


def test_the_gps_error_has_the_receivers_cep() -> None:
    # u-blox NEO-6: 2.5 m CEP: half the fixes within 2.5 m of the truth (over many receivers)
    misses = []
    for seed in range(400):
        w = world("", seed=seed)
        fix = w.step(TICK, Actuation()).fixes["gps"]
        north = (fix.latitude_deg - 48.1173) * 111_200  # (m a degree of latitude there, ~)
        east = (fix.longitude_deg - 11.516667) * 111_320 * math.cos(math.radians(48.1173))
        misses.append(math.hypot(north, east))
    assert statistics.median(misses) == pytest.approx(2.5, rel=0.12)


def test_the_gps_fix_moves_with_the_body() -> None:
    w = world("[world]\nnoise = false\n")
    before = w.step(TICK, Actuation()).fixes["gps"]
    drive(w, 1.0, 1.0, 4.0)
    after = w.step(w.t_us + TICK, Actuation()).fixes["gps"]
    east = (after.longitude_deg - before.longitude_deg) * 111_320 * math.cos(math.radians(48.1173))
    assert east == pytest.approx(w.body.x, rel=0.01)  # the world's x is east
    assert after.latitude_deg == pytest.approx(before.latitude_deg, abs=1e-9)


def test_the_battery_drains_under_the_motors_and_sags_with_their_current() -> None:
    board = {**ROVER, "transducers": [*ROVER["transducers"],
             {"name": "battery", "id": 10, "driver": "battery", "pin": 26}]}  # fmt: skip
    w = world("", board)
    rest = w.step(TICK, Actuation()).volts["battery"]
    frames = drive(w, 1.0, 1.0, 5.0)
    assert frames[1].volts["battery"] < rest - 0.1  # (starting: near their stall current)
    assert w.charge < 0.9


def test_servos_and_steppers_turn_no_faster_than_their_parts() -> None:
    w = world("[world]\nnoise = false\n")
    act = Actuation(steppers={"mast": (800, True)})  # half a turn, at once
    w.step(TICK, act)
    w.step(w.t_us + 50_000, act)
    assert w.turned["mast"] == pytest.approx(2 * math.pi * 5 * 0.06, rel=1e-6)  # 5 rev/s
    w.step(w.t_us + 100_000, act)
    assert w.turned["mast"] == pytest.approx(math.pi)  # (there: it stays)
    servo = {"name": "pan", "id": 11, "driver": "servo", "pin": 15, "call": "a2j_pan"}
    w = world("", {**ROVER, "transducers": [*ROVER["transducers"], servo]})
    act = Actuation(servos={"pan": 1500 + 300})  # (span 1200 us: +-90 degrees) 45 degrees
    w.step(TICK, act)
    w.step(w.t_us + 100_000, act)
    assert math.degrees(w.turned["pan"]) == pytest.approx(250 * 0.11)  # HS-645MG: 0.24 s/60 deg


def test_events_block_fail_slip_and_push() -> None:
    text = """
[world]
noise = false
[[events]]
at_s = 0.1
kind = "block"
part = "sonar"
distance_m = 0.2
for_s = 0.5
[[events]]
at_s = 0.1
kind = "fail"
part = "tof"
[[events]]
at_s = 0.0
kind = "slip"
part = "wheel_l"
fraction = 1.0
"""
    w = world(text)
    frames = drive(w, 0.5, 0.5, 1.0)
    assert frames[20].ranges["sonar"] == 0.2 and frames[70].ranges["sonar"] is None
    assert frames[20].failed == {"tof": "silent"}
    assert w.body.yaw > 0  # the left wheel slipped: the body turned left
    assert counts(frames, "wheel_l") == counts(frames, "wheel_r")  # (it counted all the same)


def test_a_push_by_hand_moves_the_body_and_the_imu_feels_it() -> None:
    w = world("[world]\nnoise = false\n[start]\nyaw_deg = 90\n", ROVER)
    drive(w, 0, 0, 0.1)
    w.command("push", {"dx_m": 0.3, "dy_m": -0.1, "over_s": 0.5})  # (the body's axes)
    frames = drive(w, 0, 0, 1.0)
    assert (w.body.x, w.body.y) == (pytest.approx(0.1), pytest.approx(0.3))  # facing north
    ax = [f.imus["imu"].accel[0] for f in frames]
    assert max(ax) > 1.0 and min(ax) < -1.0  # it sped up, then slowed down
    assert all(f.imus["imu"].accel[2] == pytest.approx(G) for f in frames)
    with pytest.raises(ValueError, match="is in a wall"):
        w.command("place", {"x_m": 4.95, "y_m": 0.0})
    w.command("place", {"x_m": 1.0, "y_m": 2.0, "yaw_deg": 180})
    drive(w, 0, 0, 0.02)
    assert (w.body.x, w.body.y, math.degrees(w.body.yaw)) == (1.0, 2.0, pytest.approx(180))


def test_drive_parameters_come_from_the_world_file() -> None:
    spec = replace(WorldSpec(), drive=Drive(wheel_radius_m=0.05, counts_per_rev=1000))
    w = World(spec, ROVER, 0)
    frames = drive(w, 1.0, 1.0, 1.0)
    rolled = counts(frames, "wheel_l") * 2 * math.pi * 0.05 / 1000
    assert rolled == pytest.approx(w.body.x, abs=0.001)
