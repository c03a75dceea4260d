"""The one-reading types: ``sensor_msgs/msg/MagneticField`` (a compass's x, y, z in its
``unit``: tesla out), ``std_msgs/msg/Bool`` (a digital input: true when active; the message has
no header, so its time is the one every recorder and the Zenoh attachment carry), and
``sensor_msgs/msg/BatteryState`` (the ``battery`` driver: 0 pack voltage in V, 1 charge as a
fraction 0..1 from the driver's curve)."""

from __future__ import annotations

import math
from typing import Any

from .common import Ctx, StandardMapping, no_channel, si_value

MAGNETIC_FIELD = "sensor_msgs/msg/MagneticField"
BOOL = "std_msgs/msg/Bool"
BATTERY_STATE = "sensor_msgs/msg/BatteryState"
#: the battery's chemistry, from its descriptor's model text -> POWER_SUPPLY_TECHNOLOGY_*
_TECHNOLOGY = (("lifepo", 4), ("life", 4), ("lipo", 3), ("li-po", 3), ("li-ion", 2),
               ("lion", 2), ("nimh", 1), ("nicd", 5), ("limn", 6))  # fmt: skip


def magnetic_field(c: Ctx) -> list[StandardMapping]:
    import numpy as np

    if c.t.chan_count != 3:
        raise ValueError(f"{c.board}/{c.t.name}: MagneticField wants three channels (x, y, z)")
    Field, Vector3 = c.T(MAGNETIC_FIELD), c.T("geometry_msgs/msg/Vector3")
    t = c.t

    def build_field(host_ns: list[int], values: list[Any]) -> bytes:
        x, y, z = (math.nan if v is None else si_value(t, v) for v in values)  # tesla
        msg = Field(
            header=c.header(max(host_ns)),
            magnetic_field=Vector3(x=x, y=y, z=z),
            magnetic_field_covariance=np.zeros(9, dtype=np.float64),  # unknown
        )
        return c.cdr(msg, MAGNETIC_FIELD)

    return [StandardMapping(MAGNETIC_FIELD, "field", no_channel, build_field, frame=c.frame)]


def boolean(c: Ctx) -> list[StandardMapping]:
    Bool = c.T(BOOL)

    def build_bool(ch: int, ns: int, value: Any) -> bytes:
        return c.cdr(Bool(data=bool(value)), BOOL)

    return [StandardMapping(BOOL, "active", build_bool, frame=c.frame)]


def technology(model: str) -> int:
    text = model.lower().replace(" ", "")
    return next((code for key, code in _TECHNOLOGY if key in text), 0)  # 0: UNKNOWN


def battery(c: Ctx) -> list[StandardMapping]:
    import numpy as np

    if c.t.chan_count != 2:
        raise ValueError(f"{c.board}/{c.t.name}: BatteryState wants the battery driver's layout")
    State = c.T(BATTERY_STATE)
    tech = technology(c.t.model)
    extra = {"temperature": math.nan, "cell_temperature": np.array([], dtype=np.float32)}
    extra = {k: v for k, v in extra.items() if k in State.__dataclass_fields__}  # (Humble on)

    def build_battery(host_ns: list[int], values: list[Any]) -> bytes | None:
        volts, charge = values
        if volts is None:
            return None
        msg = State(
            header=c.header(host_ns[0]),
            voltage=float(volts),
            current=math.nan,
            charge=math.nan,
            capacity=math.nan,
            design_capacity=math.nan,
            percentage=math.nan if charge is None else float(charge),
            power_supply_status=0,  # UNKNOWN: a divider cannot tell charging from not
            power_supply_health=0,
            power_supply_technology=tech,
            present=True,
            cell_voltage=np.array([], dtype=np.float32),  # (the pack only)
            location="",
            serial_number="",
            **extra,
        )
        return c.cdr(msg, BATTERY_STATE)

    return [StandardMapping(BATTERY_STATE, "battery_state", no_channel, build_battery,
                            frame=c.frame)]  # fmt: skip
