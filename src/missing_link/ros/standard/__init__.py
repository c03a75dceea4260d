"""Standard ROS message types for every driver, by default, beside the thesis-format topic.

Which types a transducer gets is decided from its descriptor, as every runtime describes a
driver alike (MicroPython and AVR boards from the same board file, the virtual boards): the
descriptor's ``ros=`` when it asks for one, else the driver's ``prefix`` (board/drivers/*.py),
else its unit and kind; docs/ros.md has the table.  Each type is published on
``/<board>/<name>/<suffix>``, stamped with the sample's synchronised host time, its
``frame_id`` the transducer's (``FrameId``: the host's key, the descriptor's, or
``<board>/<name>``), in SI units (REP 103).

==========================  ===================================  =========================
driver (descriptor prefix)  types (topic suffix)                 module
==========================  ===================================  =========================
mpu6050 (imu)               Imu (imu), Temperature (temperature) :mod:`.imu`
quadrature (quad)           JointState (joint_states)            :mod:`.joints`
servo, stepper, hbridge     JointState (joint_states)            :mod:`.joints`
sharp, srf02, hcsr04, tof   Range (range)                        :mod:`.ranges`
gps_nmea (gps)              NavSatFix (fix), TimeReference       :mod:`.gnss`
compass                     MagneticField (field)                :mod:`.simple`
digital (gpio switch)       std_msgs Bool (active)               :mod:`.simple`
battery                     BatteryState (battery_state)         :mod:`.simple`
==========================  ===================================  =========================

Actuators take ``std_msgs/msg/Float64`` in SI units on ``/<board>/<name>/command``
(:func:`command_kind`, :func:`.joints.raw_command`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from ...descriptors import Transducer
from . import gnss, imu, joints, ranges, simple
from .common import (
    UNIT_TO_SI,
    Ctx,
    FrameId,
    FrameIds,
    StandardMapping,
    StdOptions,
    check_frame_id,
    si_value,
)
from .joints import FLOAT64, JOINT_STATE, raw_command

__all__ = [
    "FLOAT64",
    "JOINT_STATE",
    "UNIT_TO_SI",
    "FrameId",
    "FrameIds",
    "StandardMapping",
    "StdOptions",
    "check_frame_id",
    "command_kind",
    "frame_of",
    "mappings_for",
    "raw_command",
    "si_value",
    "standard_kind",
]

RANGE, NAV_SAT_FIX = ranges.RANGE, gnss.NAV_SAT_FIX
MAGNETIC_FIELD, IMU = simple.MAGNETIC_FIELD, imu.IMU
BOOL, BATTERY_STATE = simple.BOOL, simple.BATTERY_STATE
IMU_K, ENCODER, RANGER, GPS, COMPASS, DIGITAL, BATTERY = (
    "imu", joints.ENCODER, "range", "gps", "compass", "bool", "battery",
)  # fmt: skip
STEPPER, HBRIDGE, POSITION = joints.STEPPER, joints.HBRIDGE, joints.POSITION
#: the drivers' descriptor prefixes (board/drivers/*.py; "hs645" is the thesis rig's servo)
BY_PREFIX = {
    "imu": IMU_K, "quad": ENCODER, "servo": POSITION, "hs645": POSITION, "stepper": STEPPER,
    "motor": HBRIDGE, "sharp": RANGER, "srf02": RANGER, "ultrasonic": RANGER, "tof": RANGER,
    "gps": GPS, "compass": COMPASS, "battery": BATTERY,
}  # fmt: skip
#: what a descriptor's ``ros=`` may ask for
SUPPORTED = (RANGE, JOINT_STATE, NAV_SAT_FIX, MAGNETIC_FIELD, IMU, BOOL, BATTERY_STATE)
_LENGTH, _ANGLE = ("mm", "cm", "m"), ("deg", "rad", "rev")
_JOINT_KINDS = (ENCODER, STEPPER, HBRIDGE, POSITION)
#: a digital input's channel: the digital driver's uint8 0/1 (255 N/A), or a bool
_DIGITAL_LAYOUT = (("uint8_t", 255), ("bool", 0), ("bool", 1))


def _by_driver(t: Transducer) -> str | None:
    kind = BY_PREFIX.get(t.prefix)
    if kind is not None:
        return kind
    if t.prefix == "gpio" and not t.is_actuator and (t.dtype, t.na) in _DIGITAL_LAYOUT:
        return DIGITAL  # (the digital driver's 0/1 with 255 as N/A: a switch, a bumper)
    unit = t.unit or ""
    if not t.is_actuator and unit in _LENGTH:
        return RANGER
    if t.is_actuator and unit in _ANGLE:
        return POSITION
    if unit == "duty":
        return HBRIDGE
    if unit == "count" and not t.is_actuator:
        return ENCODER
    return None


def standard_kind(t: Transducer, board: str = "board") -> str | None:
    """The family of standard types ``t`` maps to, or None.  Raises ValueError for a ``ros=``
    this host cannot map (the caller reports it; the thesis-format topic still goes out)."""
    wanted = t.options.get("ros")
    if not wanted:
        return _by_driver(t)
    if wanted not in SUPPORTED:
        raise ValueError(
            f"{board}/{t.name}: ros={wanted} is not supported (supported: {', '.join(SUPPORTED)})"
        )
    driver = _by_driver(t)
    if wanted == JOINT_STATE:
        return driver if driver in _JOINT_KINDS else POSITION
    return {RANGE: RANGER, NAV_SAT_FIX: GPS, MAGNETIC_FIELD: COMPASS, IMU: IMU_K, BOOL: DIGITAL,
            BATTERY_STATE: BATTERY}[wanted]  # fmt: skip


def command_kind(t: Transducer) -> str | None:
    """How an actuator's standard command converts (:func:`.joints.raw_command`); None for a
    sensor."""
    if not t.is_actuator:
        return None
    kind = _by_driver(t)
    return kind if kind in (STEPPER, HBRIDGE) else POSITION


def frame_of(t: Transducer, board: str, options: StdOptions) -> str:
    """A transducer's frame id before any change at run time: the host's key (the daemon's
    configuration), else the descriptor's ``frame_id``, else ``<board>/<name>``."""
    return options.frame_id or t.options.get("frame_id") or f"{board}/{t.name}"


_BUILDERS: dict[str, Callable[[Ctx], list[StandardMapping]]] = {
    IMU_K: imu.build,
    RANGER: ranges.build,
    GPS: gnss.build,
    COMPASS: simple.magnetic_field,
    DIGITAL: simple.boolean,
    BATTERY: simple.battery,
}


def mappings_for(
    t: Transducer,
    board: str,
    typestore: Any,
    frame: FrameId | None = None,
    options: StdOptions | None = None,
    settings: Callable[[], Mapping[str, Any]] = dict,
) -> list[StandardMapping]:
    """The standard types of ``t`` (none when it maps to none or its options turn them off).
    Raises ValueError when one cannot be made (an unsupported ``ros=``, an encoder without its
    counts per revolution): the caller reports it."""
    opts = options or StdOptions()
    if not opts.standard:
        return []
    kind = standard_kind(t, board)
    if kind is None:
        return []
    if frame is None:
        frame = FrameId(frame_of(t, board, opts))
    c = Ctx(board, t, typestore, frame, opts, settings)
    if kind in _JOINT_KINDS:
        return joints.build(c, kind)
    return _BUILDERS[kind](c)
