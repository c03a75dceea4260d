"""Standard ROS types for every driver (ros/standard): which types each board driver's
descriptor gets, and that each message says what the part measured in SI units, with the
datasheet's limits and noise; decoded by rosbags, not by our code."""

from __future__ import annotations

import math
from typing import Any

import pytest
from rosbags.typesys import Stores, get_typestore

from missing_link.board.drivers import DRIVERS, driver_class
from missing_link.board.firmware import describe
from missing_link.daemon.session.actuators import Actuators
from missing_link.daemon.session.board_topics import si_command
from missing_link.descriptors import Transducer, parse_line
from missing_link.ros.standard import (
    FrameId,
    FrameIds,
    StdOptions,
    command_kind,
    mappings_for,
    raw_command,
    standard_kind,
)
from missing_link.ros.standard.imu import variances
from missing_link.topics import Command

STORE = get_typestore(Stores.ROS2_JAZZY)
IMU_TYPE = "sensor_msgs/msg/Imu"
G = 9.80665
#: a minimal board file entry per driver (its pins; what it needs)
ENTRIES: dict[str, dict[str, Any]] = {
    "quadrature": {"pin_a": 2, "pin_b": 3},
    "sharp_gp2y0a02": {"pin": 26},
    "srf02": {"bus": "i2c0"},
    "servo": {"pin": 15},
    "digital": {"pin": 14},
    "analog": {"pin": 27},
    "mpu6050": {"bus": "i2c0"},
    "trigger": {"pin": 16},
    "gps_nmea": {"uart": 1},
    "hmc5883l": {"bus": "i2c0"},
    "qmc5883l": {"bus": "i2c0"},
    "hbridge": {"in1": 12, "in2": 13},
    "stepper": {"step_pin": 20, "dir_pin": 21},
    "hcsr04": {"trig_pin": 14, "echo_pin": 15},
    "vl53l0x": {"bus": "i2c0"},
    "battery": {"pin": 26},
}
#: what each driver is published as, beside its thesis-format topic
EXPECTED = {
    "quadrature": [("sensor_msgs/msg/JointState", "joint_states")],
    "sharp_gp2y0a02": [("sensor_msgs/msg/Range", "range")],
    "srf02": [("sensor_msgs/msg/Range", "range")],
    "servo": [("sensor_msgs/msg/JointState", "joint_states")],
    "digital": [("std_msgs/msg/Bool", "active")],
    "analog": [],
    "mpu6050": [("sensor_msgs/msg/Imu", "imu"), ("sensor_msgs/msg/Temperature", "temperature")],
    "trigger": [],
    "gps_nmea": [
        ("sensor_msgs/msg/NavSatFix", "fix"),
        ("sensor_msgs/msg/TimeReference", "time_reference"),
    ],
    "hmc5883l": [("sensor_msgs/msg/MagneticField", "field")],
    "qmc5883l": [("sensor_msgs/msg/MagneticField", "field")],
    "hbridge": [("sensor_msgs/msg/JointState", "joint_states")],
    "stepper": [("sensor_msgs/msg/JointState", "joint_states")],
    "hcsr04": [("sensor_msgs/msg/Range", "range")],
    "vl53l0x": [("sensor_msgs/msg/Range", "range")],
    "battery": [("sensor_msgs/msg/BatteryState", "battery_state")],
}


def of_driver(driver: str, **entry: Any) -> Transducer:
    """The descriptor a board running this driver sends (MicroPython and AVR describe a board
    file entry alike: board/firmware.py's describe), parsed as the host parses it."""
    e = {"name": driver[:12], "id": 1, "driver": driver, **ENTRIES[driver], **entry}
    return parse_line(describe(e, driver_class(driver)).descriptor_line())


def maps(t: Transducer, **kw: Any) -> Any:
    return mappings_for(t, "bot", STORE, **kw)


def decode(cdr: bytes | None, type_name: str) -> Any:
    assert cdr is not None
    return STORE.deserialize_cdr(cdr, type_name)


def ns(k: int) -> int:
    return 1_700_000_000_000_000_000 + k * 20_000_000  # 20 ms apart


@pytest.mark.parametrize("driver", sorted(DRIVERS))
def test_every_driver_gets_its_standard_types(driver: str) -> None:
    assert driver in EXPECTED, f"a new driver {driver}: say which standard types it gets"
    t = of_driver(
        driver, **({"options": {"counts_per_rev": 2048}} if driver == "quadrature" else {})
    )
    got = [(m.type_name, m.suffix) for m in maps(t)]
    assert got == EXPECTED[driver]
    for m in maps(t):
        assert m.type_name in STORE.types  # every typestore (every face) knows it
    assert (command_kind(t) is not None) == hasattr(driver_class(driver), "command")


def test_the_thesis_sims_descriptors_map_too() -> None:
    quad = parse_line("quad,0,quad,HEDS-6500,2,int16_t,-1,unit=count,kind=sensor")
    servo = parse_line(
        "servo,3,hs645,HS-645MG,1,int8_t,-128,kind=actuator,call=a2j_set_servo,unit=deg,"
        "scale=0.708661,ros=sensor_msgs/msg/JointState"
    )
    ir = parse_line(
        "dist_ir,1,sharp,GP2Y0A02YK,8,uint16_t,0,unit=mm,min=200,max=1500,ros=sensor_msgs/msg/Range"
    )
    assert [standard_kind(t) for t in (quad, servo, ir)] == ["encoder", "position", "range"]
    with pytest.raises(ValueError, match="ros=sensor_msgs/msg/LaserScan is not supported"):
        standard_kind(parse_line("x,1,p,m,1,uint8_t,0,ros=sensor_msgs/msg/LaserScan"))


def test_imu_at_rest_reads_one_g_without_orientation_and_datasheet_noise() -> None:
    imu, temp = maps(of_driver("mpu6050"))
    assert imu.sample is not None and temp.sample is not None
    values = [0.0, 0.0, G, 25.0, 0.0, 0.0, 0.0]
    msg = decode(imu.sample([ns(1)] * 7, values), "sensor_msgs/msg/Imu")
    a = msg.linear_acceleration
    assert math.hypot(a.x, a.y, a.z) == pytest.approx(9.81, abs=0.01)
    assert msg.orientation_covariance[0] == -1  # no orientation (REP 145)
    assert msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == ns(1)
    assert msg.header.frame_id == "bot/mpu6050"
    # the datasheet's noise at the driver's defaults: +-2 g, +-250 deg/s, DLPF 3 (44/42 Hz)
    accel = (400e-6 * G) ** 2 * 44 + (2 * G / 32768) ** 2 / 12
    gyro = math.radians(0.005) ** 2 * 42 + math.radians(250 / 32768) ** 2 / 12
    assert list(msg.linear_acceleration_covariance) == pytest.approx(
        [accel, 0, 0, 0, accel, 0, 0, 0, accel]
    )
    assert list(msg.angular_velocity_covariance)[::4] == pytest.approx([gyro] * 3)
    # the datasheet's own total: 0.05 deg/s rms at DLPF 2 (98 Hz)
    assert math.degrees(math.sqrt(variances(2, 250, 2)[1])) == pytest.approx(0.05, rel=0.02)
    t = decode(temp.sample([ns(1)] * 7, values), "sensor_msgs/msg/Temperature")
    assert t.temperature == 25.0 and t.header.frame_id == "bot/mpu6050"


def test_an_imu_vector_with_an_na_axis_is_no_estimate_not_nan() -> None:
    imu, _ = maps(of_driver("mpu6050"))
    assert imu.sample is not None
    # (the message's rule: element 0 of the covariance -1 means "disregard the estimate")
    no_accel = [None, 0.0, G, 25.0, 0.1, 0.2, 0.3]
    msg = decode(imu.sample([0, *[ns(1)] * 6], no_accel), "sensor_msgs/msg/Imu")
    a, w = msg.linear_acceleration, msg.angular_velocity
    assert (a.x, a.y, a.z) == (0.0, 0.0, 0.0) and msg.linear_acceleration_covariance[0] == -1
    assert (w.x, w.y, w.z) == (0.1, 0.2, 0.3) and msg.angular_velocity_covariance[0] > 0
    no_gyro = [0.0, 0.0, G, 25.0, 0.1, math.nan, 0.3]
    msg = decode(imu.sample([ns(2)] * 7, no_gyro), "sensor_msgs/msg/Imu")
    assert msg.angular_velocity_covariance[0] == -1 and msg.angular_velocity.y == 0.0
    assert msg.linear_acceleration.z == G and msg.linear_acceleration_covariance[0] > 0
    neither = [None, None, None, 25.0, None, None, 0.3]
    assert imu.sample([0, 0, 0, ns(3), 0, 0, ns(3)], neither) is None


def test_an_imu_vector_with_an_infinite_axis_is_no_estimate_either() -> None:
    """A float channel, or a board's scale= beyond float range, gives an infinite axis: no
    more a reading than a NaN is."""
    imu, _ = maps(of_driver("mpu6050"))
    assert imu.sample is not None
    msg = decode(imu.sample([ns(1)] * 7, [math.inf, 0.0, G, 25.0, 0.1, 0.2, 0.3]), IMU_TYPE)
    a, w = msg.linear_acceleration, msg.angular_velocity
    assert (a.x, a.y, a.z) == (0.0, 0.0, 0.0) and msg.linear_acceleration_covariance[0] == -1
    assert (w.x, w.y, w.z) == (0.1, 0.2, 0.3) and msg.angular_velocity_covariance[0] > 0
    msg = decode(imu.sample([ns(2)] * 7, [0.0, 0.0, G, 25.0, 0.1, 0.2, -math.inf]), IMU_TYPE)
    assert msg.angular_velocity.z == 0.0 and msg.angular_velocity_covariance[0] == -1
    assert msg.linear_acceleration.z == G and msg.linear_acceleration_covariance[0] > 0
    assert imu.sample([ns(3)] * 7, [math.inf, 0.0, G, 25.0, math.inf, 0.2, 0.3]) is None


def test_imu_covariance_follows_the_boards_range_and_filter() -> None:
    settings = {"mpu6050.accel_g": 2, "mpu6050.gyro_dps": 250, "mpu6050.dlpf": 3}
    imu, _ = maps(of_driver("mpu6050"), settings=lambda: settings)
    assert imu.sample is not None
    before = decode(imu.sample([ns(1)] * 7, [0.0] * 7), "sensor_msgs/msg/Imu")
    settings.update({"mpu6050.accel_g": 16, "mpu6050.gyro_dps": 2000, "mpu6050.dlpf": 0})
    after = decode(imu.sample([ns(2)] * 7, [0.0] * 7), "sensor_msgs/msg/Imu")
    accel, gyro = variances(16, 2000, 0)
    assert after.linear_acceleration_covariance[0] == pytest.approx(accel)
    assert after.angular_velocity_covariance[0] == pytest.approx(gyro)
    assert after.angular_velocity_covariance[0] > before.angular_velocity_covariance[0] * 3


@pytest.mark.parametrize(
    ("driver", "radiation", "lo", "hi", "fov_deg"),
    [
        ("sharp_gp2y0a02", 1, 0.20, 1.50, 5.0),
        ("srf02", 0, 0.16, 6.0, 55.0),
        ("hcsr04", 0, 0.02, 4.0, 15.0),
        ("vl53l0x", 1, 0.03, 2.0, 25.0),
    ],
)
def test_ranges_carry_their_datasheets_limits(
    driver: str, radiation: int, lo: float, hi: float, fov_deg: float
) -> None:
    t = of_driver(driver)
    (m,) = maps(t)
    raw = {"srf02": 123, "hcsr04": 1234, "vl53l0x": 500, "sharp_gp2y0a02": 800}[driver]
    msg = decode(m.build(0, ns(1), raw), "sensor_msgs/msg/Range")
    assert (msg.radiation_type, msg.min_range, msg.max_range) == (
        radiation,
        pytest.approx(lo),
        pytest.approx(hi),
    )
    assert msg.field_of_view == pytest.approx(math.radians(fov_deg))
    unit = {"cm": 0.01, "mm": 0.001}[str(t.unit)]
    assert msg.range == pytest.approx(raw * unit) and lo <= msg.range <= hi
    # the host's key wins over the datasheet's (a shroud, a narrower cone)
    (m,) = maps(t, options=StdOptions(field_of_view=0.1))
    assert decode(m.build(0, ns(1), raw), "sensor_msgs/msg/Range").field_of_view == pytest.approx(
        0.1
    )


def test_encoder_joint_state_in_radians_over_the_counters_wrap() -> None:
    quad = parse_line("quad,0,quad,HEDS-6500,2,int16_t,-1,unit=count,counts_per_rev=2000")
    (m,) = maps(quad)
    assert m.sample is not None
    js = lambda k, values: decode(m.sample([ns(k)] * 2, values), "sensor_msgs/msg/JointState")  # noqa: E731
    rad = 2 * math.pi / 2000
    first = js(0, [32000, -5])  # the board's own counts: its angle since power-up
    assert first.name == ["bot/quad/0", "bot/quad/1"]
    assert list(first.position) == pytest.approx([32000 * rad, -5 * rad])
    assert all(math.isnan(v) for v in first.velocity)
    second = js(1, [-32536, -5])  # +1000 counts across the int16 wrap, in 20 ms
    assert second.position[0] == pytest.approx(33000 * rad)  # half a turn (pi) on
    assert second.velocity[0] == pytest.approx(math.pi / 0.020)
    assert second.velocity[1] == 0.0
    missed = js(2, [None, -5])  # the board says an edge was missed
    assert math.isnan(missed.position[0]) and math.isnan(missed.velocity[0])
    after = js(3, [-32036, -5])
    assert after.position[0] == pytest.approx(33500 * rad)
    assert math.isnan(after.velocity[0])  # no speed across a missed edge


def test_an_encoders_angle_survives_a_daemon_restart() -> None:
    """Position is the board's count, not counts since the daemon's first sample: a daemon
    that starts again (a new mapping) says the angle the board has (issue 45.6)."""
    quad = parse_line("quad,0,quad,HEDS-6500,1,int32_t,-2147483648,unit=count,counts_per_rev=2000")
    before, after = maps(quad)[0], maps(quad)[0]
    assert before.sample is not None and after.sample is not None
    for k, count in enumerate((0, 700, 1400)):
        last = decode(before.sample([ns(k)], [count]), "sensor_msgs/msg/JointState")
    again = decode(after.sample([ns(9)], [1500]), "sensor_msgs/msg/JointState")  # restarted
    assert last.position[0] == pytest.approx(1400 * 2 * math.pi / 2000)
    assert again.position[0] == pytest.approx(1500 * 2 * math.pi / 2000)  # not 0 rad


def test_an_encoder_without_counts_per_rev_says_what_to_set() -> None:
    t = of_driver("quadrature")
    with pytest.raises(ValueError, match=r'"options": \{"counts_per_rev": N\} on its board file'):
        maps(t)
    (m,) = maps(t, options=StdOptions(counts_per_rev=400))  # the host's key does it
    assert m.type_name == "sensor_msgs/msg/JointState"


def test_servo_stepper_and_hbridge_joint_states() -> None:
    (servo,) = maps(of_driver("servo"))
    (stepper,) = maps(of_driver("stepper"))
    (motor,) = maps(of_driver("hbridge"))
    assert servo.sample and stepper.sample and motor.sample
    s = decode(servo.sample([ns(1)], [40]), "sensor_msgs/msg/JointState")
    assert s.name == ["bot/servo"] and s.position[0] == pytest.approx(math.radians(40 * 0.708661))
    assert len(s.velocity) == 0 and len(s.effort) == 0
    st = decode(stepper.sample([ns(1)] * 2, [0.25, -0.5]), "sensor_msgs/msg/JointState")
    assert st.name == ["bot/stepper"]
    assert (st.position[0], st.velocity[0]) == (pytest.approx(math.pi / 2), pytest.approx(-math.pi))
    mo = decode(motor.sample([ns(1)], [-0.25]), "sensor_msgs/msg/JointState")
    assert list(mo.effort) == [-0.25] and len(mo.position) == 0


def test_standard_commands_convert_si_to_what_each_actuator_takes() -> None:
    servo, stepper, motor = of_driver("servo"), of_driver("stepper"), of_driver("hbridge")
    assert raw_command(servo, command_kind(servo))(0.5) == round(math.degrees(0.5) / 0.708661)
    assert raw_command(stepper, command_kind(stepper))(math.pi) == pytest.approx(0.5)  # rev
    assert raw_command(motor, command_kind(motor))(-0.75) == -0.75  # duty
    sent: list[Any] = []
    acts = Actuators(lambda: sent.append("wake"), lambda why: None)
    handle = si_command(servo, raw_command(servo, "position"), acts.handler(servo))
    handle(STORE.types["std_msgs/msg/Float64"](data=0.5))  # as a face decodes it
    handle(Command([0.5], 1_900_000_000_000_000_000))  # timed: kept as timed
    assert acts._pending["servo"][1] == b"\x28" and acts._timed[0][1:3] == (
        b"\x28",  # (40, packed as the servo's int8 where it arrived)
        1_900_000_000_000_000_000,
    )
    for bad in (3.0, math.nan, True, "x"):  # beyond the servo's +-90 degrees, or no number
        with pytest.raises(ValueError):
            handle(bad)


def test_gps_fix_and_a_time_reference_per_pps_edge() -> None:
    gps = parse_line(
        "gps,0,gps,NMEA 0183,10,int32_t,-2147483648,kind=sensor,ros=sensor_msgs/msg/NavSatFix"
    )
    fix, ref = maps(gps)
    assert (fix.suffix, ref.suffix) == ("fix", "time_reference")
    assert fix.sample is not None and ref.sample is not None
    day, ms = 8847, (12 * 3600 + 35 * 60 + 19) * 1000  # 23 March 1994 12:35:19 UTC
    values = [481173000, 115166666, 545400, 1, 8, 90, 11523, 8440, day, ms]
    f = decode(fix.sample([ns(1)] * 10, values), "sensor_msgs/msg/NavSatFix")
    assert (f.latitude, f.altitude, f.status.status) == (pytest.approx(48.1173), 545.4, 0)
    r = decode(ref.sample([ns(1)] * 10, values), "sensor_msgs/msg/TimeReference")
    assert r.header.stamp.sec * 10**9 + r.header.stamp.nanosec == ns(1)  # the PPS edge
    assert r.time_ref.sec == 764426119 and r.time_ref.nanosec == 0 and r.source == "gps"
    assert ref.sample([ns(2)] * 8 + [0, 0], [*values[:8], None, None]) is None  # no edge
    old = parse_line("gps,0,gps,NMEA 0183,8,int32_t,-2147483648,ros=sensor_msgs/msg/NavSatFix")
    (only_fix,) = maps(old)  # a driver's 8 channels of before: NavSatFix only
    assert only_fix.suffix == "fix"


def test_bool_battery_and_magnetic_field() -> None:
    (active,) = maps(of_driver("digital"))
    assert decode(active.build(0, ns(1), 1), "std_msgs/msg/Bool").data is True
    (battery,) = maps(of_driver("battery", model="2S LiPo"))
    assert battery.sample is not None
    b = decode(battery.sample([ns(1)] * 2, [7.4, 0.4]), "sensor_msgs/msg/BatteryState")
    assert (b.voltage, b.percentage) == (pytest.approx(7.4), pytest.approx(0.4))
    assert b.power_supply_technology == 3 and b.present and math.isnan(b.current)
    assert battery.sample([0, 0], [None, None]) is None
    (field,) = maps(of_driver("qmc5883l"))
    assert field.sample is not None
    m = decode(field.sample([ns(1)] * 3, [2e-5, -1e-5, 4e-5]), "sensor_msgs/msg/MagneticField")
    assert (m.magnetic_field.x, m.magnetic_field.z) == (pytest.approx(2e-5), pytest.approx(4e-5))


def test_frame_id_from_the_host_the_descriptor_or_the_name_and_changeable() -> None:
    t = of_driver("vl53l0x", options={"frame_id": "front_tof"})
    (m,) = maps(t)
    assert decode(m.build(0, ns(1), 500), "sensor_msgs/msg/Range").header.frame_id == "front_tof"
    (m,) = maps(t, options=StdOptions(frame_id="tof_link"))  # the host's key wins
    assert decode(m.build(0, ns(1), 500), "sensor_msgs/msg/Range").header.frame_id == "tof_link"
    frames = FrameIds()
    frame = frames.holder("vl53l0x", "bot/vl53l0x")
    (m,) = maps(of_driver("vl53l0x"), frame=frame)
    heard: list[str] = []
    frame.listeners.append(heard.append)
    frame.set("nose")  # at run time: the next message says it
    assert decode(m.build(0, ns(2), 500), "sensor_msgs/msg/Range").header.frame_id == "nose"
    assert heard == ["nose"]
    assert frames.holder("vl53l0x", "bot/vl53l0x") is frame and frame.value == "nose"  # kept
    assert FrameIds().holder("x", "a").value == "a"
    for bad in ("", "a b", "x\n"):
        with pytest.raises(ValueError, match="frame_id"):
            FrameId(bad)


def test_standard_types_off_per_transducer() -> None:
    assert maps(of_driver("vl53l0x"), options=StdOptions(standard=False)) == []


@pytest.mark.parametrize("frame", ["", "a", "abc", "rig/imu"])
@pytest.mark.parametrize("names", [[], ["x"], ["ab", "rover/wheel_l"]])
def test_the_packed_joint_state_is_byte_for_byte_rosbags(frame: str, names: list[str]) -> None:
    import numpy as np

    from missing_link.ros.standard.joints import joint_state_cdr

    T = STORE.types
    n = len(names)
    cases: list[Any] = [(None, None, None), ([1.5] * n, None, [-0.25] * n), ([0.0] * n,) * 3]
    for fields in cases:
        arrays = [np.array(f if f is not None else [], dtype=np.float64) for f in fields]
        stamp = T["builtin_interfaces/msg/Time"](sec=1_700_000_001, nanosec=123)
        msg = T["sensor_msgs/msg/JointState"](
            header=T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame),
            name=names,
            position=arrays[0],
            velocity=arrays[1],
            effort=arrays[2],
        )
        want = bytes(STORE.serialize_cdr(msg, "sensor_msgs/msg/JointState"))
        assert joint_state_cdr(1_700_000_001_000_000_123, frame, names, fields) == want
