"""The robot-level JointState (daemon/joints.py): its configuration, and the router's rules on
virtual time: where a JointState command goes (by index, or in order over the joints that take
a field, as ros2_control's topic-based interface writes it), timed commands, refusals, and the
command timeout that stops what is driven by velocity or effort."""

from __future__ import annotations

import math
import tomllib
from types import SimpleNamespace
from typing import Any

import pytest

from missing_link.daemon.config import parse_config
from missing_link.daemon.joints import JointRouter, interface_of
from missing_link.daemon.ros_config import JointSpec
from missing_link.descriptors import parse_line
from missing_link.errors import ConfigError

NOW = 1_800_000_000_000_000_000
ROBOT = """
[joints]
command_timeout = 0.5
[joints.left_wheel]
state = "rover/wheel_l"
command = "rover/motor_l"
[joints.right_wheel]
state = "rover/wheel_r"
command = "rover/motor_r"
[joints.pan]
state = "rig/servo"
command = "rig/servo"
[joints.mast]
command = "rover/mast"
[joints.odo_b]
state = "thesis/quad/1"
"""
MOTOR = parse_line("motor_l,2,motor,H-bridge,1,float,nan,unit=duty,kind=actuator,call=a")
STEPPER = parse_line("mast,8,stepper,A4988,2,float,nan,unit=rev,kind=actuator,call=b")
SERVO = parse_line("servo,3,servo,HS-645MG,1,int8_t,-128,unit=deg,kind=actuator,call=c")


def router(text: str = ROBOT, remap: dict[str, str] | None = None) -> JointRouter:
    cfg = parse_config(tomllib.loads(text))
    assert cfg.joints is not None
    return JointRouter(cfg.joints, remap or {})


def iface(r: JointRouter) -> Any:
    kinds = {"left_wheel": "effort", "right_wheel": "effort", "pan": "position", "mast": "position"}
    return lambda k: kinds[r.names[k]]


def stamp(ns: int) -> Any:
    return SimpleNamespace(stamp=SimpleNamespace(sec=ns // 10**9, nanosec=ns % 10**9))


def test_a_command_by_name_and_index_goes_to_each_actuators_standard_command() -> None:
    r = router()
    msg = {"name": ["pan", "left_wheel"], "position": [0.5, math.nan], "effort": [math.nan, -0.3]}
    out, errors = r.route(msg, NOW, 0.0, iface(r))
    assert errors == []
    assert [(topic, c.values, c.at_ns) for topic, c in out] == [
        ("/rig/servo/command", [0.5], None),
        ("/rover/motor_l/command", [-0.3], None),
    ]


def test_shorter_arrays_hold_the_joints_that_take_the_field_in_order() -> None:
    """joint_state_topic_hardware_interface pushes one value per command interface, so with a
    position joint and two effort joints: position=[p], effort=[e1, e2]."""
    r = router()
    msg = SimpleNamespace(
        header=stamp(0),
        name=["left_wheel", "pan", "right_wheel"],
        position=[0.25],
        velocity=[],
        effort=[0.1, 0.2],
    )
    out, errors = r.route(msg, NOW, 0.0, iface(r))
    assert errors == []
    got = {topic: c.values[0] for topic, c in out}
    assert got == {
        "/rover/motor_l/command": 0.1,
        "/rig/servo/command": 0.25,
        "/rover/motor_r/command": 0.2,
    }


def test_a_future_stamp_makes_a_timed_command_a_past_one_acts_now() -> None:
    r = router()
    later = NOW + 400_000_000
    out, _ = r.route(SimpleNamespace(header=stamp(later), name=["pan"], position=[0.1]),
                     NOW, 0.0, iface(r))  # fmt: skip
    assert out[0][1].at_ns == later
    out, _ = r.route(SimpleNamespace(header=stamp(NOW - 1), name=["pan"], position=[0.1]),
                     NOW, 0.0, iface(r))  # fmt: skip
    assert out[0][1].at_ns is None


def test_what_cannot_be_routed_is_said_and_the_rest_goes() -> None:
    r = router()
    msg = {"name": ["nope", "odo_b", "pan", "left_wheel"], "position": [1.0, 2.0, 0.5, 3.0]}
    out, errors = r.route(msg, NOW, 0.0, iface(r))
    assert [t for t, _ in out] == ["/rig/servo/command"]
    assert any("nope: no such joint takes commands" in e for e in errors)
    assert any("odo_b: no such joint takes commands" in e for e in errors)  # state only
    assert any("left_wheel: no effort in the command" in e for e in errors)
    _, errors = r.route({"name": ["pan", "mast"], "position": [1.0, 2.0, 3.0]}, NOW, 0.0, iface(r))
    assert any("position has 3 values for 2 names" in e for e in errors)


def test_joints_driven_by_effort_stop_when_commands_stop_position_joints_hold() -> None:
    r = router()
    r.route({"name": ["pan", "left_wheel"], "position": [0.5, 0.0], "effort": [0, 0.4]},
            NOW, 10.0, iface(r))  # fmt: skip
    assert r.expired(10.4) == []
    assert r.expired(10.6) == [(0, "/rover/motor_l/command")]  # once ...
    assert r.expired(11.0) == []
    r.route({"name": ["left_wheel"], "effort": [0.4]}, NOW, 11.0, iface(r))  # ... until driven
    assert r.expired(11.6) == [(0, "/rover/motor_l/command")]
    off = router(ROBOT.replace("command_timeout = 0.5", "command_timeout = 0"))
    off.route({"name": ["left_wheel"], "effort": [0.4]}, NOW, 0.0, iface(off))
    assert off.expired(1e6) == []


def test_a_joints_state_from_its_sensor_and_its_actuators_effort() -> None:
    r = router()
    assert set(r.sources) == {
        "/rover/wheel_l/joint_states", "/rover/motor_l/joint_states",
        "/rover/wheel_r/joint_states", "/rover/motor_r/joint_states",
        "/rig/servo/joint_states", "/rover/mast/joint_states", "/thesis/quad/joint_states",
    }  # fmt: skip
    assert r.on_state("/rover/wheel_l/joint_states", ([1.5], [2.0], [])) == [0]
    assert r.on_state("/rover/motor_l/joint_states", ([], [], [0.25])) == [0]
    assert r.joint(0) == (1.5, 2.0, 0.25)
    assert r.on_state("/thesis/quad/joint_states", ([9.0, 7.0], [0.0, 1.0], [])) == [4]
    assert r.joint(4)[:2] == (7.0, 1.0)  # channel 1 of the transducer
    p, v, e = r.joint(3)  # the mast: nothing heard yet
    assert math.isnan(p) and math.isnan(v) and math.isnan(e)
    remapped = router(remap={"/rover/wheel_l": "/wheels/left"})
    assert "/wheels/left/joint_states" in remapped.sources


def test_the_interface_follows_the_actuator_and_its_mode() -> None:
    j = JointSpec("mast", None, "rover/mast")
    assert interface_of(j, STEPPER, {"mast.mode": "position"}) == "position"
    assert interface_of(j, STEPPER, {"mast.mode": "velocity"}) == "velocity"
    with pytest.raises(ValueError, match=r"set mast.mode = velocity"):
        interface_of(JointSpec("mast", None, "rover/mast", "velocity"), STEPPER, {})
    assert interface_of(JointSpec("w", None, "rover/motor_l"), MOTOR, {}) == "effort"
    with pytest.raises(ValueError, match="takes effort"):
        interface_of(JointSpec("w", None, "rover/motor_l", "velocity"), MOTOR, {})
    assert interface_of(JointSpec("pan", None, "rig/servo"), SERVO, {}) == "position"


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ('[joints.a]\nstate = "rover"', "joints.a.state: 'rover'"),
        ('[joints.a]\ncommand = "rover/motor/0"', "joints.a.command"),
        ("[joints.a]\ninterface = 'torque'\nstate = 'a/b'", "joints.a.interface: one of"),
        ("[joints.a]\nwhat = 1", "joints.a.what: unknown key"),
        ("[joints.a]", "a joint needs a state, a command or both"),
        ('[joints]\nstate_topic = "joints"', "joints.state_topic"),
        ("[joints]\ncommand_timeout = -1", "joints.command_timeout"),
        ('[joints]\ncommand_topic = "/joint_states"', "must differ from state_topic"),
        ("[boards.rover.ros.wheel_l]\ncounts_per_rev = 0", "counts_per_rev"),
        ('[boards.rover.ros.wheel_l]\nframe_id = "a b"', "frame_id"),
        ('[boards.rover.ros.wheel_l]\nthesis = "no"', "expected a bool"),
        ("[boards.rover.ros.wheel_l]\nfov = 1", "unknown key"),
        ("[daemon]\nstandard_types = 1", "daemon.standard_types: expected a bool"),
    ],
)
def test_config_errors_name_the_table_and_key(text: str, words: str) -> None:
    with pytest.raises(ConfigError, match=r"^f\.toml: ") as e:
        parse_config(tomllib.loads(text), "f.toml")
    assert words in str(e.value) and "\n" not in str(e.value)


def test_the_switches_and_per_transducer_keys() -> None:
    cfg = parse_config(
        tomllib.loads(
            "[daemon]\nthesis_types = false\n"
            '[boards.rover.ros.wheel_l]\ncounts_per_rev = 1440\nframe_id = "left_wheel"\n'
            "standard = false\n"
        )
    )
    o = cfg.std_options("rover", "wheel_l")
    assert (o.counts_per_rev, o.frame_id, o.standard, o.thesis) == (
        1440.0,
        "left_wheel",
        False,
        False,
    )
    other = cfg.std_options("rover", "tof")
    assert (other.standard, other.thesis) == (True, False)  # daemon-wide: no thesis topics
