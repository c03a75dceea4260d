"""What the standard types cost on the sample path: per sample of each driver's layout, the
standard messages its mapping builds (ros/standard), next to two references measured in the same
run: the thesis-format message of the same sample (the CDR encoder every sample already pays)
and, for JointState, the same message built as rosbags objects and serialised (what the packed
encoder replaced).

    .venv/bin/python bench/bench_standard.py [--seconds 1.0]
"""

from __future__ import annotations

import argparse
import platform
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from rosbags.typesys import Stores, get_typestore

from missing_link.descriptors import parse_line
from missing_link.ros.msgs import CdrEncoder
from missing_link.ros.standard import mappings_for

STORE = get_typestore(Stores.ROS2_JAZZY)
NS = 1_700_000_000_000_000_000
CASES: dict[str, tuple[str, list[Any]]] = {
    "quadrature, 2 ch": ("quad,0,quad,HEDS-6500,2,int16_t,-1,unit=count,counts_per_rev=2000",
                         [100, 200]),
    "mpu6050, 7 ch": ("imu,5,imu,MPU-6050,7,float,nan,unit=SI", [0.0, 0.0, 9.8, 25.0, 0, 0, 0]),
    "vl53l0x, 1 ch": ("tof,7,tof,VL53L0X,1,uint16_t,0,unit=mm,min=30,max=2000", [500]),
    "sharp, 8 ch": ("ir,1,sharp,GP2Y0A02YK,8,uint16_t,0,unit=mm", [800] * 8),
    "servo, 1 ch": ("servo,3,servo,HS-645MG,1,int8_t,-128,unit=deg,scale=0.708661,"
                    "kind=actuator,call=x", [40]),
    "gps_nmea, 8 ch": ("gps,0,gps,NMEA 0183,8,int32_t,-2147483648",
                       [481173000, 115166666, 545400, 1, 8, 90, 11523, 8440]),
    "gps_nmea, 10 ch, PPS": ("gps,0,gps,NMEA 0183,10,int32_t,-2147483648",
                       [481173000, 115166666, 545400, 1, 8, 90, 11523, 8440, 8847, 45319000]),
    "battery, 2 ch": ("battery,0,battery,2S Li-ion,2,float,nan,unit=V", [7.4, 0.4]),
}  # fmt: skip


def per_call_us(fn: Callable[[int], object], seconds: float) -> float:
    n, k = 0, 1
    start = time.perf_counter()
    while time.perf_counter() - start < seconds:
        for i in range(k):
            fn(i)
        n += k
        k *= 2
    return (time.perf_counter() - start) / n * 1e6


def standard_of(line: str, values: list[Any]) -> Callable[[int], object]:
    maps = mappings_for(parse_line(line), "bot", STORE)

    def run(i: int) -> None:
        ns = [NS + i * 1000] * len(values)
        for m in maps:
            if m.sample is not None:
                m.sample(ns, values)
            else:
                for ch, v in enumerate(values):
                    m.build(ch, ns[ch], v)

    return run


def thesis_of(line: str, values: list[Any]) -> Callable[[int], object]:
    enc = CdrEncoder(parse_line(line))
    return lambda i: enc.encode([NS + i * 1000] * len(values), values)


def rosbags_joint_state(i: int) -> bytes:
    T = STORE.types
    stamp = T["builtin_interfaces/msg/Time"](sec=1_700_000_000, nanosec=i)
    msg = T["sensor_msgs/msg/JointState"](
        header=T["std_msgs/msg/Header"](stamp=stamp, frame_id="bot/quad"),
        name=["bot/quad/0", "bot/quad/1"],
        position=np.array([0.1, 0.2]),
        velocity=np.array([1.0, 2.0]),
        effort=np.array([], dtype=np.float64),
    )
    return bytes(STORE.serialize_cdr(msg, "sensor_msgs/msg/JointState"))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=1.0)
    a = ap.parse_args()
    print(f"Standard types per sample, {platform.python_implementation()} "
          f"{platform.python_version()}, one core")  # fmt: skip
    head = f"{'layout':<20} | {'standard µs':>11} | {'thesis µs (ref)':>15} | {'ratio':>5}"
    print(head)
    print("-" * len(head))
    for name, (line, values) in CASES.items():
        std = per_call_us(standard_of(line, values), a.seconds)
        ref = per_call_us(thesis_of(line, values), a.seconds)
        print(f"{name:<20} | {std:>11.1f} | {ref:>15.1f} | {std / ref:>5.1f}")
    packed = per_call_us(standard_of(*CASES["quadrature, 2 ch"]), a.seconds)
    objects = per_call_us(rosbags_joint_state, a.seconds)
    print(f"\nJointState of 2 joints: packed {packed:.1f} µs (with the unwrap and speed), "
          f"rosbags objects + serialize_cdr {objects:.1f} µs (reference)")  # fmt: skip


if __name__ == "__main__":
    main()
