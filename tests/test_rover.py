"""The thesis's remaining parts on the MicroPython firmware (examples/boards/rover.py) under the
real MicroPython interpreter, each driver against a device simulated at its interface from its
datasheet (src/missing_link/virtual/world/devices.py): a GPS's NMEA bytes and PPS edges at a
UART and a pin, a compass's registers, an H-bridge's PWM inputs, a step/dir driver counting
pulses, an HC-SR04's echo, a VL53L0X's registers; and the failsafe stopping the motors when the
host is gone."""

from __future__ import annotations

import itertools
import math
import struct
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from rosbags.typesys import Stores, get_typestore

from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config
from missing_link.host.board import Board
from missing_link.topics import Update
from missing_link.transport import open_transport

from .helpers import FirmwareSim, daemon_up, wait_for

ROOT = Path(__file__).resolve().parent.parent
ROVER = ROOT / "examples" / "boards" / "rover.py"
STORE = get_typestore(Stores.ROS2_JAZZY)
pytestmark = [pytest.mark.micropython, pytest.mark.slow]


@pytest.fixture(scope="module")
def sim() -> Iterator[FirmwareSim]:
    with FirmwareSim(ROVER) as s:
        yield s


@pytest.fixture
def rover(sim: FirmwareSim) -> Iterator[Daemon]:
    with daemon_up(sim.url) as d:
        yield d


def listen(d: Daemon, name: str) -> list[Update]:
    got: list[Update] = []
    d.subscribe(f"/rover/{name}", got.append, queue=0)
    return got


def board_us_of(sim: FirmwareSim, ticks: list[int]) -> list[int]:
    """ticks_us readings at the simulated device in the board's clock (it extends ticks_us)."""
    board_now, raw_now = sim.ctl("import time; result = (rt.clock(), time.ticks_us())")
    return [t - raw_now + board_now for t in ticks]


def test_gps_fix_from_nmea_stamped_at_its_pps_edge(rover: Daemon, sim: FirmwareSim) -> None:
    got = listen(rover, "gps")
    fixes = listen(rover, "gps/fix")
    assert wait_for(lambda: len(got) >= 2 and fixes, 10)
    lat, lon, alt, fix, sats, hdop, speed, course = got[-1].values[:8]
    # 4807.0380 N, 01131.0000 E (NMEA's own example): degrees + minutes / 60, in 1e-7 degree
    assert (lat, lon) == (481173000, 115166666)
    assert (alt, fix, sats, hdop) == (545400, 1, 8, 90)  # mm, GPS fix, 8 used, 0.9
    assert (speed, course) == (22400 * 1852 // 3600, 8440)  # 22.4 kn in mm/s, 84.4 deg
    pps = board_us_of(sim, sim.ctl("result = WORLD.devices['gps'].pps_at"))
    # the fix belongs to the second its PPS edge began (the wasm port's clock counts whole ms)
    assert min(abs(got[-1].board_us[0] - p) for p in pps) <= 1000
    # the standard type, read by rosbags (not our code): NavSatFix on /rover/gps/fix
    fix = STORE.deserialize_cdr(fixes[-1].cdr, "sensor_msgs/msg/NavSatFix")
    assert (fix.latitude, fix.longitude) == (pytest.approx(48.1173), pytest.approx(11.5166666))
    assert fix.altitude == pytest.approx(545.4) and fix.status.status == 0
    assert fix.position_covariance[0] == pytest.approx((0.9 * 5) ** 2)
    assert fix.position_covariance_type == 1


def test_gps_bad_checksums_are_counted_and_dropped(rover: Daemon, sim: FirmwareSim) -> None:
    before = sim.ctl("result = fw.drivers['gps'].checksum_errors")
    sim.ctl("WORLD.devices['gps'].bad_every = 2")  # every other sentence: every GGA

    def errors_now() -> int:
        return int(sim.ctl("result = fw.drivers['gps'].checksum_errors"))

    wait_for(lambda: errors_now() >= before + 2, 10)  # (the fix before them long published)
    got = listen(rover, "gps")
    mark = errors_now()
    wait_for(lambda: errors_now() >= mark + 2, 10)  # two GGAs more, none of them good
    errors = errors_now()
    assert errors >= before + 2 and got == []  # no GGA passed its checksum: no sample
    sim.ctl("WORLD.devices['gps'].bad_every = 0; WORLD.devices['gps'].quality = 0")
    assert wait_for(lambda: len(got) >= 1, 5)
    lat, lon, alt, fix, sats, _hdop, _speed, _course = got[-1].values[:8]
    assert (lat, lon, alt, fix) == (None, None, None, 0) and sats == 8  # no fix: no position
    sim.ctl("WORLD.devices['gps'].quality = 1")


def test_compass_in_tesla_through_its_ranges(rover: Daemon, sim: FirmwareSim) -> None:
    got = listen(rover, "compass")
    field = listen(rover, "compass/field")
    assert wait_for(lambda: len(got) >= 3 and field, 5)
    assert got[-1].values == pytest.approx([2e-5, -1e-5, 4e-5], rel=1e-6)  # 0.2 -0.1 0.4 G
    msg = STORE.deserialize_cdr(field[-1].cdr, "sensor_msgs/msg/MagneticField").magnetic_field
    assert (msg.x, msg.y, msg.z) == (pytest.approx(2e-5), pytest.approx(-1e-5), pytest.approx(4e-5))
    assert sim.ctl("result = WORLD.i2c[(0, 0x0D)].regs[9]") == (1 << 4) | (1 << 2) | 1  # 8 G
    rover.configure("rover", {"compass.range_gauss": 2})
    n = len(got)
    assert wait_for(lambda: len(got) >= n + 3, 5)
    assert sim.ctl("result = WORLD.i2c[(0, 0x0D)].regs[9]") == (1 << 2) | 1  # 2 G, 50 Hz
    assert got[-1].values == pytest.approx([2e-5, -1e-5, 4e-5], rel=1e-4)
    sim.ctl("WORLD.i2c[(0, 0x0D)].field_gauss = (3.0, 0.1, 0.1)")  # beyond 2 G: overflow
    n = len(got)
    assert wait_for(lambda: len(got) >= n + 2 and got[-1].values == [None] * 3, 5)
    sim.ctl("WORLD.i2c[(0, 0x0D)].field_gauss = (0.2, -0.1, 0.4)")
    rover.configure("rover", {"compass.range_gauss": 8})


def test_hbridge_ramps_reverses_and_brakes(rover: Daemon, sim: FirmwareSim) -> None:
    got = listen(rover, "motor_l")
    state = "result = WORLD.devices['motor_l'].state()"
    rover.send("/rover/motor_l/cmd", 0.5)
    assert wait_for(lambda: sim.ctl(state) == (0.5, "drive"), 5), sim.ctl(state)
    assert wait_for(lambda: got[-1].values[0] == 0.5, 5), got[-1]  # (its report on its way)
    # Ramped at 4 a second, a step at least every 20 ms of the board's clock: a step never
    # moves more than the ramp allows for the board's time since the one before (a board the
    # host starves takes fewer, larger steps: how many is the machine's, not the firmware's)
    # and there are steps on the way, not one jump.
    steps = [(u.board_us[0], u.values[0]) for u in got]
    assert len(steps) >= 3, steps
    assert steps[0][1] <= 4.0 * 0.020 + 1e-6, steps  # the first, as the command arrives
    for (t0, a), (t1, b) in itertools.pairwise(steps):
        assert 0 < b - a <= 4.0 * max((t1 - t0) / 1e6, 0.020) + 1e-6, steps
    rover.send("/rover/motor_l/cmd", -0.25)
    assert wait_for(lambda: sim.ctl(state) == (-0.25, "drive"), 5), sim.ctl(state)
    assert sim.ctl("result = WORLD.duty(12)") == 0.0  # reverse: IN1 low, IN2 driven
    rover.send("/rover/motor_l/cmd", 0.0)
    assert wait_for(lambda: sim.ctl(state) == (0.0, "brake"), 5)  # stop = brake: both high
    errors = rover.status()[0]["command_errors"]
    rover.send("/rover/motor_l/cmd", 1.5)  # refused by the board, said and counted
    assert wait_for(lambda: rover.status()[0]["command_errors"] == errors + 1, 5)
    assert sim.ctl(state) == (0.0, "brake")


def test_stepper_moves_to_a_position_and_turns_at_a_speed(rover: Daemon, sim: FirmwareSim) -> None:
    got = listen(rover, "mast")
    dev = "WORLD.devices['mast']"
    rover.send("/rover/mast/cmd", 0.25)  # a quarter turn: 50 full steps x 8 microsteps
    assert wait_for(lambda: sim.ctl(f"result = {dev}.position") == 400, 10)
    assert wait_for(lambda: got and got[-1].values == [0.25, 0.0], 5), got[-3:]
    assert sim.ctl(f"result = {dev}.enabled()") is True
    peak = max(u.values[1] for u in got)
    assert 0 < peak <= 1.0  # max_speed 1 rev/s
    rover.send("/rover/mast/cmd", 0.0)  # back home
    assert wait_for(lambda: sim.ctl(f"result = {dev}.position") == 0, 10)
    rover.configure("rover", {"mast.mode": "velocity"})
    rover.send("/rover/mast/cmd", -0.5)  # turning backwards at half a rev/s
    assert wait_for(lambda: sim.ctl(f"result = {dev}.position") < -400, 10)
    rover.send("/rover/mast/cmd", 0.0)  # decelerates to a stop
    driver = "d = fw.drivers['mast']; result = (d.position, d.speed, d._mode, d._goal, d._next)"
    assert wait_for(lambda: got[-1].values[1] == 0.0, 5), (got[-3:], sim.ctl(driver))
    stopped = sim.ctl(f"result = {dev}.position")
    time.sleep(0.3)
    assert sim.ctl(f"result = {dev}.position") == stopped
    rover.configure("rover", {"mast.mode": "position"})


def test_hcsr04_echo_to_distance_at_the_air_temperature(rover: Daemon, sim: FirmwareSim) -> None:
    got = listen(rover, "sonar")
    assert wait_for(lambda: len(got) >= 2, 5)
    assert got[-1].values[0] == pytest.approx(1000, abs=1)  # 1 m at 20 degC (343.4 m/s)
    sim.ctl("WORLD.devices['sonar'].temperature_c = 35.0")  # warm air: a shorter echo ...
    n = len(got)
    assert wait_for(lambda: len(got) >= n + 2, 5)
    assert got[-1].values[0] == pytest.approx(1000 * 343.4 / 352.51, abs=2)  # ... read at 20
    rover.configure("rover", {"sonar.temperature_c": 35.0})  # the driver told the air's
    n = len(got)
    assert wait_for(lambda: len(got) >= n + 2, 5)
    assert got[-1].values[0] == pytest.approx(1000, abs=1)
    sim.ctl("WORLD.devices['sonar'].distance_mm = None")  # nothing in range
    timeouts = sim.ctl("result = fw.drivers['sonar'].timeouts")
    n = len(got)
    assert wait_for(lambda: len(got) >= n + 2 and got[-1].values == [None], 5)
    assert sim.ctl("result = fw.drivers['sonar'].timeouts") > timeouts
    sim.ctl("WORLD.devices['sonar'].distance_mm = 1000; WORLD.devices['sonar'].temperature_c = 20")
    rover.configure("rover", {"sonar.temperature_c": 20.0})


def test_vl53l0x_ranges_after_its_start_up(rover: Daemon, sim: FirmwareSim) -> None:
    got = listen(rover, "tof")
    assert wait_for(lambda: len(got) >= 2, 5)
    assert got[-1].values == [500]
    assert sim.ctl("result = WORLD.i2c[(0, 0x29)].regs[0x89] & 1") == 1  # 2.8 V I/O set
    sim.ctl("WORLD.i2c[(0, 0x29)].target = False")  # nothing in front: phase fail, N/A
    n = len(got)
    assert wait_for(lambda: len(got) >= n + 2 and got[-1].values == [None], 5)
    sim.ctl("WORLD.i2c[(0, 0x29)].target = True; WORLD.i2c[(0, 0x29)].distance_mm = 321")
    rover.configure("rover", {"tof.mode": "continuous"})
    n = len(got)
    assert wait_for(lambda: len(got) >= n + 2 and got[-1].values == [321], 5)
    # started once: no start per sample any more (read once it ranges continuously: the
    # start may come before the configure's reply)
    rangings = sim.ctl("result = WORLD.i2c[(0, 0x29)].rangings")
    n = len(got)
    assert wait_for(lambda: len(got) >= n + 3 and got[-1].values == [321], 5)
    assert sim.ctl("result = WORLD.i2c[(0, 0x29)].rangings") == rangings
    rover.configure("rover", {"tof.mode": "single"})


def test_failsafe_stops_the_motors_when_the_host_is_gone() -> None:
    """A host that drives the motors and then goes silent: after failsafe_ms (300) they brake
    and the stepper lets go; a host that says goodbye: at once.  (A rover of its own: the
    module's daemon keeps the other one's link alive.)"""
    sim = FirmwareSim(ROVER)
    try:
        _failsafe(sim)
    finally:
        sim.close()


def _failsafe(sim: FirmwareSim) -> None:
    state = "result = (WORLD.devices['motor_r'].state(), WORLD.devices['mast'].enabled())"
    for goodbye in (False, True):
        board = Board(open_transport(sim.url), timeout=5.0)
        try:
            board.handshake()
            trips = struct.unpack("<II", board.call_ok("a2jFailsafe"))[0]
            board.call_ok("a2j_motor_r", struct.pack("<f", 0.75))
            board.call_ok("a2j_mast", struct.pack("<f", 5.0))  # a long way: still turning

            sent = [0.0]  # when the host last sent the board a frame: the failsafe counts from it

            def driving(board: Board = board, sent: list[float] = sent) -> bool:  # (the host talks)
                sent[0] = time.monotonic()  # (before: the board hears it no earlier)
                board.call("a2jEcho")  # (it answers 0xBA, as the 2014 firmware's)
                (duty, mode), enabled = sim.ctl(state)
                return bool(abs(duty - 0.75) < 1e-3 and mode == "drive" and enabled)

            assert wait_for(driving, 5)
            t0 = sent[0]  # the host's last frame (the poll after it may have been slow)
            if goodbye:
                board.call_ok("a2jGoodbye")
                assert sim.ctl(state) == ((0.0, "brake"), False)
            else:
                assert wait_for(lambda: sim.ctl(state) == ((0.0, "brake"), False), 5)
                assert time.monotonic() - t0 >= 0.25  # not before failsafe_ms (300 ms)
            now_trips, age = struct.unpack("<II", board.call_ok("a2jFailsafe"))
            assert now_trips == trips + 2 and age < 5000  # the two commanded, just now
            debug = board.call_ok("a2jDebug").decode()
            assert "failsafe: motor_r safe" in debug and "failsafe: mast safe" in debug
        finally:
            board.close()
    moved = sim.ctl("result = WORLD.devices['mast'].position")
    time.sleep(0.3)
    assert sim.ctl("result = WORLD.devices['mast'].position") == moved  # no step since
    assert not math.isnan(moved)


def test_hmc5883l_pwm_dir_bridge_and_a_limp_servo() -> None:
    """tests/boards/parts-pico.py: the HMC5883L (X Z Y order, the skipped reading after a gain
    change, -4096 on overflow), a PWM/DIR bridge, and a servo that goes limp (safe = limp)."""
    sim = FirmwareSim(ROOT / "tests" / "boards" / "parts-pico.py")
    try:
        with Daemon(Config(boards=[BoardSpec(sim.url, timeout=2.0)])) as d:
            assert d.wait_until_up(30)
            got: list[Update] = []
            d.subscribe("/parts/compass", got.append, queue=0)
            assert wait_for(lambda: len(got) >= 3, 5)
            # 0.2 -0.1 0.4 G at 1090 LSB/G: round(218, -109, 436) / 1090 gauss
            want = [218 / 1090 * 1e-4, -109 / 1090 * 1e-4, 436 / 1090 * 1e-4]
            assert got[-1].values == pytest.approx(want, rel=1e-6)
            d.configure("parts", {"compass.range_gauss": 0.88})  # 1370 LSB/G
            assert wait_for(lambda: sim.ctl("result = WORLD.i2c[(0, 0x1E)].regs[1]") == 0, 5)
            n = len(got)
            assert wait_for(lambda: len(got) >= n + 3, 5)
            want = [274 / 1370 * 1e-4, -137 / 1370 * 1e-4, 548 / 1370 * 1e-4]
            assert got[-1].values == pytest.approx(want, rel=1e-6)
            sim.ctl("WORLD.i2c[(0, 0x1E)].field_gauss = (0.2, 2.5, 0.4)")  # y beyond 0.88 G
            n = len(got)
            assert wait_for(lambda: len(got) >= n + 2 and got[-1].values[1] is None, 5)
            assert got[-1].values[0] is not None  # only that axis
            state = "result = WORLD.devices['motor'].state()"
            d.send("/parts/motor/cmd", -0.6)  # ramp 0: at once
            assert wait_for(lambda: sim.ctl(state)[0] == pytest.approx(-0.6, abs=1e-3), 5)
            assert sim.ctl("result = WORLD.pin(7).level") == 1  # DIR high: reverse
            d.send("/parts/servo/cmd", 50)
            assert wait_for(lambda: (sim.ctl("result = WORLD.pulse_us(15)") or 0) > 1500, 5)
        # the daemon said goodbye: the bridge coasts, the servo went limp (no more pulses); on a
        # loaded machine the interpreter may get to the goodbye after the daemon stopped waiting
        # for its answer, or trip on the host's silence (200 ms) first: safe either way
        assert wait_for(lambda: sim.ctl(state) == (0.0, "coast"), 3), sim.ctl(state)
        assert wait_for(lambda: sim.ctl("result = WORLD.pulse_us(15)") == 0, 3)
    finally:
        sim.close()
