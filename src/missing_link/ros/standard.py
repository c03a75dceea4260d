"""Standard ROS message types for transducers that ask for one (``ros=sensor_msgs/msg/Range``).

Besides its thesis-format topic ``/<board>/<name>``, such a transducer is published as the
standard type on ``/<board>/<name>/<kind>`` (``range``, ``joint_states``): one message per
channel that has a value, with frame id ``<board>/<name>/<channel>``, stamped with that
channel's host time.  Values are converted with the descriptor's ``scale``/``offset`` and its
``unit`` (mm, cm, m; deg, rad) into SI units.

Supported per channel: ``sensor_msgs/msg/Range`` and ``sensor_msgs/msg/JointState``.  Per
sample (one message from all channels, by a channel layout the descriptor's driver follows;
docs/descriptors.md): ``sensor_msgs/msg/NavSatFix`` (``gps_nmea``'s: latitude and longitude in
1e-7 degree, altitude in mm, fix quality, satellites, HDOP x 100) on ``/<board>/<name>/fix``, and
``sensor_msgs/msg/MagneticField`` (x, y, z in the descriptor's unit: T, uT or gauss) on
``/<board>/<name>/field``.  Other types (Imu) need a layout convention first; a descriptor
asking for them gets its thesis-format topic only and the daemon reports it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from ..descriptors import Transducer

RANGE = "sensor_msgs/msg/Range"
JOINT_STATE = "sensor_msgs/msg/JointState"
NAV_SAT_FIX = "sensor_msgs/msg/NavSatFix"
MAGNETIC_FIELD = "sensor_msgs/msg/MagneticField"
SUPPORTED = {RANGE: "range", JOINT_STATE: "joint_states", NAV_SAT_FIX: "fix",
             MAGNETIC_FIELD: "field"}  # fmt: skip
UNIT_TO_SI = {
    "mm": 0.001, "cm": 0.01, "m": 1.0, "deg": math.pi / 180, "rad": 1.0, "rev": 2 * math.pi,
    "T": 1.0, "uT": 1e-6, "gauss": 1e-4, "G": 1e-4,
}  # fmt: skip
#: GGA fix quality -> NavSatStatus.status (-1 no fix, 0 fix, 1 SBAS/differential, 2 GBAS/RTK)
_FIX_STATUS = {0: -1, 1: 0, 2: 1, 3: 0, 4: 2, 5: 2, 6: 0, 7: 0, 8: 0}
#: a GPS receiver's user equivalent range error (m), for a covariance from the HDOP
UERE_M = 5.0
_ULTRASOUND_HINTS = ("srf", "sonar", "ultra", "maxbotix", "hc-sr04")


@dataclass
class StandardMapping:
    type_name: str
    suffix: str
    build: Callable[[int, int, Any], bytes]  # (channel, host_ns, value) -> CDR
    #: a per-sample type: (host ns per channel, values) -> CDR, one message from every channel
    sample: Callable[[list[int], list[Any]], bytes] | None = None


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

    if wanted in (NAV_SAT_FIX, MAGNETIC_FIELD):
        return _per_sample(t, wanted, typestore, f"{board}/{t.name}")

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


def _no_channel(ch: int, ns: int, value: Any) -> bytes:
    raise ValueError("a per-sample type: built from all channels at once")


def _per_sample(t: Transducer, wanted: str, typestore: Any, frame: str) -> StandardMapping:
    T = typestore.types
    Header, Time = T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
    import numpy as np

    def stamped(ns: int) -> Any:
        sec, nsec = divmod(ns, 1_000_000_000)
        return Header(stamp=Time(sec=sec, nanosec=nsec), frame_id=frame)

    if wanted == NAV_SAT_FIX:
        if t.chan_count < 6:
            raise ValueError(f"{frame}: NavSatFix wants the gps_nmea channel layout (6 or more)")
        Fix, Status = T[NAV_SAT_FIX], T["sensor_msgs/msg/NavSatStatus"]

        def build_fix(host_ns: list[int], values: list[Any]) -> bytes:
            lat, lon, alt, quality, _sats, hdop = values[:6]
            fixed = lat is not None and lon is not None and quality
            status = _FIX_STATUS.get(int(quality or 0), 0) if fixed else -1
            cov = np.zeros(9, dtype=np.float64)
            cov_type = 0  # COVARIANCE_TYPE_UNKNOWN
            if hdop is not None:
                h = hdop / 100 * UERE_M
                cov[0] = cov[4] = h * h
                cov[8] = (2 * h) ** 2  # vertical: about twice the horizontal
                cov_type = 1  # COVARIANCE_TYPE_APPROXIMATED
            msg = Fix(
                header=stamped(max(host_ns)),
                status=Status(status=status, service=1),  # SERVICE_GPS
                latitude=lat * 1e-7 if fixed else math.nan,
                longitude=lon * 1e-7 if fixed else math.nan,
                altitude=alt / 1000 if fixed and alt is not None else math.nan,
                position_covariance=cov,
                position_covariance_type=cov_type,
            )
            return bytes(typestore.serialize_cdr(msg, NAV_SAT_FIX))

        return StandardMapping(NAV_SAT_FIX, SUPPORTED[NAV_SAT_FIX], _no_channel, build_fix)

    if t.chan_count != 3:
        raise ValueError(f"{frame}: MagneticField wants three channels (x, y, z)")
    Field, Vector3 = T[MAGNETIC_FIELD], T["geometry_msgs/msg/Vector3"]

    def build_field(host_ns: list[int], values: list[Any]) -> bytes:
        x, y, z = (math.nan if v is None else si_value(t, v) for v in values)  # tesla
        msg = Field(
            header=stamped(max(host_ns)),
            magnetic_field=Vector3(x=x, y=y, z=z),
            magnetic_field_covariance=np.zeros(9, dtype=np.float64),  # unknown
        )
        return bytes(typestore.serialize_cdr(msg, MAGNETIC_FIELD))

    return StandardMapping(MAGNETIC_FIELD, SUPPORTED[MAGNETIC_FIELD], _no_channel, build_field)
