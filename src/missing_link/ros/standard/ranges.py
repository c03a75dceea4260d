"""``sensor_msgs/msg/Range`` for rangers: one message per channel with a value, in metres, with
the radiation type, limits and field of view of the part (its datasheet; the descriptor's
``min``/``max`` and the host's ``field_of_view`` key override them)."""

from __future__ import annotations

import math
from typing import Any

from .common import Ctx, StandardMapping, si_value

RANGE = "sensor_msgs/msg/Range"
ULTRASOUND, INFRARED = 0, 1


class Part:
    def __init__(self, radiation: int, lo: float, hi: float, fov_deg: float, why: str) -> None:
        self.radiation, self.lo, self.hi = radiation, lo, hi
        self.fov = math.radians(fov_deg)
        self.why = why


#: by the driver's descriptor prefix (board/drivers/*.py; the AVR runtime describes the same)
PARTS = {
    # Sharp GP2Y0A02YK0F: 20-150 cm.  Its datasheet gives no beam angle: 5 degrees is our
    # assumption for its narrow spot (not measured); set `field_of_view` where it matters
    "sharp": Part(INFRARED, 0.20, 1.50, 5.0, "GP2Y0A02YK0F datasheet: 20-150 cm"),
    # Devantech SRF02: 16 cm (its auto-tuned minimum range) to 6 m; about 55 degrees wide as
    # read from the beam-pattern plot of its documentation (not measured here)
    "srf02": Part(ULTRASOUND, 0.16, 6.0, 55.0, "SRF02 datasheet: 16 cm-6 m, beam pattern"),
    # HC-SR04: 2 cm-4 m, "measuring angle 15 degree"
    "ultrasonic": Part(ULTRASOUND, 0.02, 4.0, 15.0, "HC-SR04 datasheet: 2 cm-4 m, 15 deg"),
    # ST VL53L0X: a 940 nm VCSEL (infrared), field of view 25 degrees, up to 2 m
    "tof": Part(INFRARED, 0.03, 2.0, 25.0, "VL53L0X datasheet DS11555: FoV 25 deg, 2 m"),
}
_ULTRASOUND_HINTS = ("srf", "sonar", "ultra", "maxbotix", "hc-sr04")


def part_of(c: Ctx) -> Part | None:
    return PARTS.get(c.t.prefix)


def build(c: Ctx) -> list[StandardMapping]:
    t = c.t
    part = part_of(c)
    Range = c.T(RANGE)
    if part is not None:
        radiation, lo, hi, fov = part.radiation, part.lo, part.hi, part.fov
    else:  # a ranger we have no datasheet for: what its descriptor says
        hint = (t.prefix + " " + t.model).lower()
        radiation = ULTRASOUND if any(h in hint for h in _ULTRASOUND_HINTS) else INFRARED
        lo, hi, fov = 0.0, math.inf, 0.0
    if "min" in t.options:
        lo = si_value(t, float(t.options["min"]))
    if "max" in t.options:
        hi = si_value(t, float(t.options["max"]))
    if c.options.field_of_view is not None:
        fov = c.options.field_of_view
    extra = {"variance": 0.0} if "variance" in Range.__dataclass_fields__ else {}  # (Jazzy on)
    frame, n = c.frame, t.chan_count

    def build_range(ch: int, ns: int, value: Any) -> bytes:
        msg = Range(
            header=c.header(ns, frame.channel(ch, n)),
            radiation_type=radiation,
            field_of_view=fov,
            min_range=lo,
            max_range=hi,
            range=si_value(t, value),
            **extra,
        )
        return c.cdr(msg, RANGE)

    return [StandardMapping(RANGE, "range", build_range, frame=frame)]
