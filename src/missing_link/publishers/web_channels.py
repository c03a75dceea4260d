"""What each channel of a transducer is, for the device console (web_model.py, console.js): its
name, the SI unit its value is shown and plotted in, the factor from the board's raw value,
the unit the part is sold in (an encoder's counts, a servo's degrees, a ranger's centimetres)
and which plot it shares (one per quantity and unit); and an actuator's control: the command
topic that takes SI, its range and its step.  Pure code: from the descriptor alone, by the
driver family the standard types use (``ros/standard``: its ``ros=``, prefix, unit).

SI here is what ROS's standard types carry (REP 103): m, rad, m/s^2, rad/s, V, s; a
magnetic field in µT (SI's prefix: tesla's values are 1e-5), a temperature in °C as
``sensor_msgs/msg/Temperature`` has it, a duty and a charge as fractions.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

from ..board.dtypes import DTYPES, FLOAT_TYPES
from ..descriptors import Transducer
from ..ros.standard import UNIT_TO_SI, standard_kind
from ..ros.standard.common import descriptor_key

G = 9.80665
DEG = math.pi / 180
#: a descriptor's unit as a person reads it (descriptors are ASCII)
SHOWN = {"us": "µs", "deg": "°"}


@dataclass(frozen=True)
class Channel:
    name: str
    unit: str  #: what the value is shown and plotted in (SI)
    scale: float  #: raw (as the board sends it) -> unit: raw * scale + offset
    offset: float = 0.0
    part_unit: str = ""  #: the unit the part is sold in ("": none besides SI)
    part_scale: float = 1.0  #: unit -> part unit
    plot: str = ""  #: the plot it shares (channels of one quantity and unit)


def _named(names: list[str], unit: str, scale: float, part: str = "", part_scale: float = 1.0,
           plot: str = "") -> list[Channel]:  # fmt: skip
    return [Channel(n, unit, scale, 0.0, part, part_scale, plot or unit) for n in names]


def _each(t: Transducer, what: str) -> list[str]:
    """One name per channel: ``what`` alone, or ``<name>/<ch>`` (eight rangers of one kind)."""
    return [what] if t.chan_count == 1 else [f"{t.name}/{ch}" for ch in range(t.chan_count)]


def _unit_factor(t: Transducer) -> float:
    """Raw -> the descriptor's unit (its scale; the offset is the channel's)."""
    return float(t.options.get("scale", 1.0))


def channels(t: Transducer) -> list[Channel]:
    """Every channel of ``t``, named, in SI, with the part's unit where it has one."""
    try:
        kind = standard_kind(t)
    except ValueError:  # (a ros= this host cannot map: shown as the board says)
        kind = None
    unit = t.unit or ""
    raw = _unit_factor(t)
    if kind == "imu" and t.chan_count == 7:
        return [
            *_named(["ax", "ay", "az"], "m/s²", 1.0, "g", 1 / G, "acceleration"),
            *_named(["temperature"], "°C", 1.0, plot="temperature"),
            *_named(["gx", "gy", "gz"], "rad/s", 1.0, "°/s", 1 / DEG, "angular velocity"),
        ]
    if kind == "encoder":
        cpr = _counts_per_rev(t)
        if cpr is None:  # (no counts per turn: counts are all it can say)
            return _named(_each(t, "count"), "count", raw, plot="count")
        return _named(_each(t, "angle"), "rad", raw * 2 * math.pi / cpr, "counts",
                      cpr / (2 * math.pi), "angle")  # fmt: skip
    if kind == "position":
        per = UNIT_TO_SI.get(unit, 1.0)  # (the descriptor's unit: deg) -> rad
        return [Channel(n, "rad", raw * per, _offset(t) * per, SHOWN.get(unit, unit), 1 / per,
                        "angle") for n in _each(t, "angle")]  # fmt: skip
    if kind == "stepper":
        return [*_named(["position"], "rad", 2 * math.pi, "rev", 1 / (2 * math.pi), "angle"),
                *_named(["speed"], "rad/s", 2 * math.pi, "rev/s", 1 / (2 * math.pi), "speed")][
            : t.chan_count
        ]  # fmt: skip
    if kind == "hbridge":
        return _named(_each(t, "duty"), "", 1.0, "%", 100.0, "duty")
    if kind == "range" and unit in UNIT_TO_SI:
        return _named(_each(t, "distance"), "m", raw * UNIT_TO_SI[unit], SHOWN.get(unit, unit),
                      1 / UNIT_TO_SI[unit], "distance")  # fmt: skip
    if kind == "compass":
        per = raw * UNIT_TO_SI.get(unit, 1.0) * 1e6  # (µT)
        return _named(["x", "y", "z"][: t.chan_count], "µT", per, "G", 0.01, "field")
    if kind == "gps" and t.chan_count >= 8:
        return _gps(t.chan_count)
    if kind == "battery" and t.chan_count == 2:
        return [*_named(["voltage"], "V", 1.0, plot="voltage"),
                *_named(["charge"], "", 1.0, "%", 100.0, "charge")]  # fmt: skip
    if unit in ("us", "ms", "s"):  # (a trigger's pulse)
        return _named(_each(t, "time"), "s", raw * UNIT_TO_SI[unit], SHOWN.get(unit, unit),
                      1 / UNIT_TO_SI[unit], "time")  # fmt: skip
    label = "" if unit == "SI" else unit
    what = "active" if kind == "bool" else "value"
    return [Channel(n, label, raw, _offset(t), plot=label or what) for n in _each(t, what)]


def _offset(t: Transducer) -> float:
    return float(t.options.get("offset", 0.0))


def _counts_per_rev(t: Transducer) -> float | None:
    text = descriptor_key(t, "counts_per_rev")
    try:
        cpr = float(text) if text is not None else None
    except ValueError:
        return None
    return cpr if cpr is not None and cpr > 0 and math.isfinite(cpr) else None


def _gps(n: int) -> list[Channel]:
    """docs/descriptors.md's layout: lat, lon (1e-7 degree), altitude (mm), fix quality,
    satellites, HDOP x 100, speed (mm/s), course (0.01 degree), the PPS edge's UTC day and ms."""
    out = [
        Channel("latitude", "°", 1e-7, plot="latitude"),
        Channel("longitude", "°", 1e-7, plot="longitude"),
        Channel("altitude", "m", 1e-3, plot="altitude"),
        Channel("fix", "", 1.0, plot="fix"),
        Channel("satellites", "", 1.0, plot="fix"),
        Channel("hdop", "", 0.01, plot="fix"),
        Channel("speed", "m/s", 1e-3, plot="speed"),
        Channel("course", "°", 0.01, plot="course"),
        Channel("utc day", "d", 1.0, plot="utc"),
        Channel("utc time", "s", 1e-3, plot="utc time"),
    ]
    return out[:n]


def control(t: Transducer, si_topic: str | None, raw_topic: str | None) -> dict[str, Any] | None:
    """An actuator's control: its SI command topic (``/<board>/<name>/command``) when the daemon
    offers one, with the range and step the actuator takes in SI (None where it has no bound:
    a field then, no slider), else its raw topic with the raw type's range."""
    if not t.is_actuator or (si_topic is None and raw_topic is None):
        return None
    ch = channels(t)[0]
    lo, hi, whole = _raw_range(t)
    step: float | None = whole
    if si_topic is None:
        return {"topic": raw_topic, "si": False, "unit": "raw", "lo": lo, "hi": hi, "step": 1,
                "part_unit": ch.unit, "part_scale": ch.scale}  # fmt: skip
    if standard_kind(t) == "hbridge":
        lo, hi, step = -1.0, 1.0, 0.01
    elif lo is not None and hi is not None:
        lo, hi = sorted((lo * ch.scale + ch.offset, hi * ch.scale + ch.offset))
        step = abs(ch.scale) if whole else None  # (one raw step: the finest it takes)
    return {"topic": si_topic, "si": True, "unit": ch.unit, "lo": lo, "hi": hi, "step": step,
            "part_unit": ch.part_unit, "part_scale": ch.part_scale, "name": ch.name}  # fmt: skip


def _raw_range(t: Transducer) -> tuple[float | None, float | None, int | None]:
    """(lo, hi, step) a command of ``t`` may have, raw: its descriptor's min and max, else its
    integer type's range less its N/A value; a float type without them has none."""
    if "min" in t.options and "max" in t.options:
        return float(t.options["min"]), float(t.options["max"]), None
    if t.dtype in FLOAT_TYPES:
        return None, None, None
    _c, _s, lo, hi = DTYPES[t.dtype]
    lo, hi = (lo + 1 if t.na == lo else lo), (hi - 1 if t.na == hi else hi)
    return float(lo), float(hi), 1


def describe(t: Transducer) -> list[dict[str, Any]]:
    """The channels as the page takes them (JSON)."""
    return [asdict(c) for c in channels(t)]
