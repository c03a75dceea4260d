"""Standard ROS message types for transducers that ask for one (``ros=sensor_msgs/msg/Range``).

Besides its thesis-format topic ``/<board>/<name>``, such a transducer is published as the
standard type on ``/<board>/<name>/<kind>`` (``range``, ``joint_states``): one message per
channel that has a value, with frame id ``<board>/<name>/<channel>``, stamped with that
channel's host time.  Values are converted with the descriptor's ``scale``/``offset`` and its
``unit`` (mm, cm, m; deg, rad) into SI units.

Supported: ``sensor_msgs/msg/Range`` and ``sensor_msgs/msg/JointState``.  Types whose channel
layout is not one scalar per channel (Imu, NavSatFix) need a layout convention first; a
descriptor asking for them gets its thesis-format topic only and the daemon reports it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from ..descriptors import Transducer

RANGE = "sensor_msgs/msg/Range"
JOINT_STATE = "sensor_msgs/msg/JointState"
SUPPORTED = {RANGE: "range", JOINT_STATE: "joint_states"}
UNIT_TO_SI = {"mm": 0.001, "cm": 0.01, "m": 1.0, "deg": math.pi / 180, "rad": 1.0}
_ULTRASOUND_HINTS = ("srf", "sonar", "ultra", "maxbotix", "hc-sr04")


@dataclass
class StandardMapping:
    type_name: str
    suffix: str
    build: Callable[[int, int, Any], bytes]  # (channel, host_ns, value) -> CDR


def si_value(t: Transducer, value: float) -> float:
    scale = float(t.options.get("scale", 1.0))
    offset = float(t.options.get("offset", 0.0))
    return (value * scale + offset) * UNIT_TO_SI.get(t.unit or "", 1.0)


def mapping_for(t: Transducer, board: str, typestore: Any) -> StandardMapping | None:
    """The standard mapping of ``t``, or None when it asks for none.  Raises ValueError for a
    type this host cannot map (the caller reports it)."""
    wanted = t.options.get("ros")
    if not wanted:
        return None
    if wanted not in SUPPORTED:
        raise ValueError(
            f"{board}/{t.name}: ros={wanted} is not supported (supported: {', '.join(SUPPORTED)})"
        )
    T = typestore.types
    Time, Header = T["builtin_interfaces/msg/Time"], T["std_msgs/msg/Header"]
    frame = [f"{board}/{t.name}/{ch}" for ch in range(t.chan_count)]

    def header(ch: int, ns: int) -> Any:
        sec, nsec = divmod(ns, 1_000_000_000)
        return Header(stamp=Time(sec=sec, nanosec=nsec), frame_id=frame[ch])

    if wanted == RANGE:
        Range = T[RANGE]
        hint = (t.prefix + " " + t.model).lower()
        radiation = 0 if any(h in hint for h in _ULTRASOUND_HINTS) else 1  # ULTRASOUND / INFRARED
        lo = si_value(t, float(t.options["min"])) if "min" in t.options else 0.0
        hi = si_value(t, float(t.options["max"])) if "max" in t.options else math.inf
        extra = {"variance": 0.0} if "variance" in Range.__dataclass_fields__ else {}

        def build_range(ch: int, ns: int, value: Any) -> bytes:
            msg = Range(
                header=header(ch, ns),
                radiation_type=radiation,
                field_of_view=0.0,
                min_range=lo,
                max_range=hi,
                range=si_value(t, value),
                **extra,
            )
            return bytes(typestore.serialize_cdr(msg, RANGE))

        return StandardMapping(RANGE, SUPPORTED[RANGE], build_range)

    JointState = T[JOINT_STATE]
    import numpy as np

    def build_joint(ch: int, ns: int, value: Any) -> bytes:
        msg = JointState(
            header=header(ch, ns),
            name=[frame[ch]],
            position=np.array([si_value(t, value)], dtype=np.float64),
            velocity=np.array([], dtype=np.float64),
            effort=np.array([], dtype=np.float64),
        )
        return bytes(typestore.serialize_cdr(msg, JOINT_STATE))

    return StandardMapping(JOINT_STATE, SUPPORTED[JOINT_STATE], build_joint)
