"""What the device console says of each channel (issue 45.7; publishers/web_channels.py): every
channel named, in SI and in the unit the part is sold in, one plot per quantity; an actuator's
control in SI with its range.  The page itself, in a real browser: tests/test_web_browser.py."""

from __future__ import annotations

import math
import tomllib
from collections.abc import Callable
from typing import Any

import pytest
from rosbags.typesys import Stores, get_typestore

from missing_link.daemon import Daemon
from missing_link.daemon.config import parse_config
from missing_link.descriptors import parse_line
from missing_link.publishers.web_channels import channels, control
from missing_link.publishers.web_model import ConsoleModel
from missing_link.ros.standard import FLOAT64
from missing_link.topics import Topic, Update

Serve = Callable[..., Any]
STORE = get_typestore(Stores.ROS2_JAZZY)
IMU = parse_line("imu,5,imu,MPU-6050,7,float,nan,kind=sensor,unit=SI,rate_hz=100")
SERVO = parse_line("servo,3,servo,HS-645MG,1,int8_t,-128,unit=deg,kind=actuator,scale=0.708661,"
                   "call=a2j_set_servo")  # fmt: skip
WHEEL = parse_line("wheel,0,quad,quadrature,1,int32_t,-2147483648,unit=count,counts_per_rev=2000")
MOTOR = parse_line("motor,2,motor,hbridge,1,float,nan,unit=duty,kind=actuator,call=a2j_motor")


def named(t: Any) -> list[tuple[str, str, str, str]]:
    return [(c.name, c.unit, c.part_unit, c.plot) for c in channels(t)]


def test_an_imu_is_seven_named_channels_on_three_plots() -> None:
    """Before: one "imu (SI)" plot of ch0..ch6 mixing m/s², °C and rad/s."""
    assert named(IMU) == [
        ("ax", "m/s²", "g", "acceleration"), ("ay", "m/s²", "g", "acceleration"),
        ("az", "m/s²", "g", "acceleration"), ("temperature", "°C", "", "temperature"),
        ("gx", "rad/s", "°/s", "angular velocity"), ("gy", "rad/s", "°/s", "angular velocity"),
        ("gz", "rad/s", "°/s", "angular velocity"),
    ]  # fmt: skip
    az, gx = channels(IMU)[2], channels(IMU)[4]
    assert az.part_scale * 9.80665 == pytest.approx(1.0)  # (1 g)
    assert gx.part_scale == pytest.approx(180 / math.pi)


def test_an_encoder_is_in_rad_and_counts() -> None:
    (c,) = channels(WHEEL)
    assert (c.name, c.unit, c.part_unit) == ("angle", "rad", "counts")
    assert 500 * c.scale == pytest.approx(math.pi / 2) and c.part_scale * c.scale == 1.0
    bare = parse_line("quad,0,quad,HEDS-6500,2,int16_t,-1,unit=count")  # (no counts per turn)
    assert named(bare) == [("quad/0", "count", "", "count"), ("quad/1", "count", "", "count")]


def test_a_servo_is_commanded_in_rad_within_its_range() -> None:
    """Before: "a raw int8_t" (typing 60 gave 42.52 deg)."""
    (c,) = channels(SERVO)
    assert (c.unit, c.part_unit) == ("rad", "°") and 40 * c.scale == pytest.approx(
        math.radians(40 * 0.708661)
    )
    got = control(SERVO, "/rig/servo/command", "/rig/servo/cmd")
    assert got is not None and got["topic"] == "/rig/servo/command" and got["si"]
    assert got["lo"] == pytest.approx(-math.radians(127 * 0.708661))
    assert got["hi"] == pytest.approx(math.radians(127 * 0.708661))  # (±90°: -128 is N/A)
    assert got["step"] == pytest.approx(math.radians(0.708661))
    raw = control(SERVO, None, "/rig/servo/cmd")  # (no standard types: the raw topic)
    assert raw is not None and (raw["si"], raw["lo"], raw["hi"]) == (False, -127, 127)
    motor = control(MOTOR, "/rover/motor/command", None)
    assert motor is not None and (motor["lo"], motor["hi"], motor["part_unit"]) == (-1, 1, "%")


def test_the_model_takes_si_commands_and_sends_si_values() -> None:
    model = ConsoleModel()
    topic = Topic.for_transducer("/rig/servo", "rig", SERVO, "missing_link_msgs")
    std = Topic.standard_type("/rig/servo/command", "rig", SERVO, FLOAT64, STORE)
    model.add_topic(topic)
    model.add_command("/rig/servo/cmd", topic, lambda c: None)
    model.add_command("/rig/servo/command", std, lambda c: None)
    (meta,) = model.snapshot()["topics"]
    assert meta["control"]["topic"] == "/rig/servo/command" and meta["layout"][0]["unit"] == "rad"
    model.add_sample(Update.build(topic=topic, board_us=[1], host_ns=[10**18], values=[40],
                                  seq=0, lost=0, recv_ns=1))  # fmt: skip
    (point,) = model.drain(1e9)["data"]["/rig/servo"]
    assert point[1] == pytest.approx(math.radians(40 * 0.708661))


def test_the_hosts_counts_per_rev_is_the_consoles_too(serve: Serve) -> None:
    """[boards.<board>.ros.<encoder>] counts_per_rev overrides the board's on every face."""
    server = serve("thesis")
    doc = tomllib.loads(f'[[board]]\nurl = "{server.url}"\n[boards.thesis.ros.quad]\n'
                        "counts_per_rev = 500\n")  # fmt: skip
    with Daemon(parse_config(doc)) as d:
        assert d.wait_until_up(10)
        quad = d.bus.topics["/thesis/quad"].transducer
    assert quad.options["counts_per_rev"] == "500"  # (the sim's descriptor says 2000)
    assert 500 * channels(quad)[0].scale == pytest.approx(2 * math.pi)
