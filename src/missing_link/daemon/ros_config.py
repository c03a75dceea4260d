"""The daemon configuration's ROS tables (config.py reads the file): the host-side keys of
each transducer's standard types (``[boards.<name>.ros.<transducer>]``) and the robot-level
joints (``[joints]``, daemon/joints.py); docs/ros.md."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from ..errors import ConfigError
from ..ros.standard import StdOptions, check_frame_id
from ..text import is_token
from ..topics import check_topic

Fail = Callable[[str, str], ConfigError]
#: config.py's check of a table's keys and value types: (table, allowed, where, fail)
Check = Callable[[Any, dict[str, Any], str, Fail], dict[str, Any]]


@dataclass(frozen=True)
class JointSpec:
    """One joint of the robot-level JointState ([joints.<name>])."""

    name: str
    #: where its state comes from: "<board>/<transducer>" or "<board>/<transducer>/<channel>"
    state: str | None
    #: the actuator its commands go to: "<board>/<transducer>" (None: state only)
    command: str | None
    #: the JointState command field it takes: position, velocity or effort (None: by driver)
    interface: str | None = None


@dataclass
class JointsConfig:
    state_topic: str = "/joint_states"
    command_topic: str = "/joint_commands"
    #: s without a command after which a joint driven by velocity or effort is stopped (0: never)
    command_timeout: float = 0.5
    joints: list[JointSpec] = field(default_factory=list)


_ROS_KEYS: dict[str, Any] = {
    "frame_id": str, "standard": bool, "thesis": bool, "counts_per_rev": (int, float),
    "field_of_view": (int, float),
}  # fmt: skip


def parse_ros(table: Any, where: str, fail: Fail, check_table: Check) -> dict[str, StdOptions]:
    if not isinstance(table, dict):
        raise fail(where, "must be tables like [boards.rover.ros.wheel_l]")
    out = {}
    for name, keys in table.items():
        at = f"{where}.{name}"
        if not is_token(name):
            raise fail(at, f"{name!r} is not a transducer name ([a-z][a-z0-9_]*)")
        check_table(keys, _ROS_KEYS, at, fail)
        if "frame_id" in keys:
            try:
                check_frame_id(keys["frame_id"])
            except ValueError as e:
                raise fail(f"{at}.frame_id", str(e)) from None
        if not keys.get("counts_per_rev", 1) > 0:
            raise fail(f"{at}.counts_per_rev", "counts (edges, x4) per revolution: above 0")
        if not 0 <= keys.get("field_of_view", 0) <= 2 * math.pi:
            raise fail(f"{at}.field_of_view", "an angle in rad, 0..2 pi")
        floats = {k: float(v) for k, v in keys.items() if k in ("counts_per_rev", "field_of_view")}
        out[name] = StdOptions(**{**keys, **floats})
    return out


_JOINT_KEYS: dict[str, Any] = {"state": str, "command": str, "interface": str}
_INTERFACES = ("position", "velocity", "effort")


def parse_joints(table: Any, fail: Fail, check_table: Check) -> JointsConfig:
    """``[joints]``: topics and timeout, then one ``[joints.<joint name>]`` per joint."""
    if not isinstance(table, dict):
        raise fail("joints", "must be a table")
    spec = JointsConfig()
    settings = {"state_topic": str, "command_topic": str, "command_timeout": (int, float)}
    for key, value in table.items():
        at = f"joints.{key}"
        if not isinstance(value, dict):
            check_table({key: value}, settings, "joints", fail)
            if key.endswith("_topic"):
                try:
                    check_topic(value)
                except ValueError as e:
                    raise fail(at, str(e)) from None
            elif not 0 <= value <= 3600:
                raise fail(at, f"{value!r} s is outside 0..3600 (0: never)")
            setattr(spec, key, float(value) if key == "command_timeout" else value)
            continue
        check_table(value, _JOINT_KEYS, at, fail)
        if not key or not key.isprintable() or " " in key:
            raise fail(at, "a joint name is printable and has no spaces")
        for k in ("state", "command"):
            ref = value.get(k)
            if ref is not None and not _joint_ref(ref, k == "state"):
                raise fail(f"{at}.{k}", f'{ref!r}: "<board>/<transducer>"' + (
                    ' or "<board>/<transducer>/<channel>"' if k == "state" else ""))  # fmt: skip
        if "state" not in value and "command" not in value:
            raise fail(at, "a joint needs a state, a command or both")
        if value.get("interface", "position") not in _INTERFACES:
            raise fail(f"{at}.interface", f"one of {', '.join(_INTERFACES)}")
        spec.joints.append(JointSpec(key, value.get("state"), value.get("command"),
                                     value.get("interface")))  # fmt: skip
    if spec.state_topic == spec.command_topic:
        raise fail("joints.command_topic", "must differ from state_topic")
    return spec


def _joint_ref(ref: str, channel_ok: bool) -> bool:
    parts = ref.split("/")
    if len(parts) == 3 and channel_ok and parts[2].isdigit():
        parts = parts[:2]
    return len(parts) == 2 and all(is_token(p) for p in parts)
