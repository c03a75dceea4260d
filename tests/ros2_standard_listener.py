"""An independent ROS 2 node for the standard types (rclpy and the message packages only;
nothing from missing_link): subscribes by standard type, publishes standard commands, reads the
graph, and prints one JSON object.

    python ros2_standard_listener.py --seconds 60 \
        --sub /rig/imu/imu=sensor_msgs/msg/Imu --sub /joint_states=sensor_msgs/msg/JointState \
        --float64 /rig/servo/command=0.5 --joint mast=position=3.14159 \
        --until-near /rig/servo/joint_states=position=0.5=0.0062 \
        --until-moved /rover/wheel_l/joint_states=position=1.5707

Every message is summarised field by field (a header as stamp_ns and frame_id, arrays as lists)
with the time it arrived (recv_ns, CLOCK_REALTIME).  Commands go out every 0.1 s once someone
listens (as a controller publishes every cycle), until every --until holds (or --seconds)."""

from __future__ import annotations

import argparse
import importlib
import json
import math
import time
from typing import Any

import rclpy


def msg_class(type_name: str) -> Any:
    pkg, _msg, name = type_name.split("/")
    return getattr(importlib.import_module(f"{pkg}.msg"), name)


def summarise(msg: Any) -> Any:
    if not hasattr(msg, "get_fields_and_field_types"):
        if isinstance(msg, (bool, int, float, str)):
            return msg
        if hasattr(msg, "__len__"):
            return [summarise(x) for x in msg]
        return float(msg)
    out: dict[str, Any] = {}
    for field in msg.get_fields_and_field_types():
        v = getattr(msg, field)
        if field == "header":
            out["stamp_ns"] = v.stamp.sec * 10**9 + v.stamp.nanosec
            out["frame_id"] = v.frame_id
        elif field in ("stamp", "time_ref"):
            out[field] = v.sec * 10**9 + v.nanosec
        else:
            out[field] = summarise(v)
    return out


def first(summary: dict[str, Any], field: str) -> float | None:
    v = summary.get(field)
    if isinstance(v, list):
        v = v[0] if v else None
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else None


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--min", type=int, default=3)
    ap.add_argument("--sub", action="append", default=[], help="TOPIC=TYPE")
    ap.add_argument("--float64", action="append", default=[], help="TOPIC=VALUE")
    ap.add_argument("--joint", action="append", default=[], help="NAME=FIELD=VALUE")
    ap.add_argument("--joint-topic", default="/joint_commands")
    ap.add_argument("--until-near", action="append", default=[], help="TOPIC=FIELD=VALUE=TOL")
    ap.add_argument("--until-moved", action="append", default=[], help="TOPIC=FIELD=DELTA")
    a = ap.parse_args()
    start_ns = time.time_ns()
    rclpy.init()
    node = rclpy.create_node("standard_listener")
    got: dict[str, list[dict[str, Any]]] = {}

    def keep(topic: str, m: Any) -> None:
        got[topic].append({**summarise(m), "recv_ns": time.time_ns()})

    for spec in a.sub:
        topic, type_name = spec.split("=")
        got[topic] = []
        node.create_subscription(msg_class(type_name), topic, lambda m, t=topic: keep(t, m), 10)
    Float64, JointState = msg_class("std_msgs/msg/Float64"), msg_class("sensor_msgs/msg/JointState")
    floats = [(node.create_publisher(Float64, t, 10), float(v)) for t, v in
              (s.split("=") for s in a.float64)]  # fmt: skip
    joints = [s.split("=") for s in a.joint]
    joint_pub = node.create_publisher(JointState, a.joint_topic, 10) if joints else None
    sent = 0

    def holds() -> bool:
        for spec in a.until_near:
            topic, field, value, tol = spec.split("=")
            if not any(
                (x := first(s, field)) is not None and abs(x - float(value)) <= float(tol)
                for s in got.get(topic, [])
            ):
                return False
        for spec in a.until_moved:
            topic, field, delta = spec.split("=")
            xs = [x for s in got.get(topic, []) if (x := first(s, field)) is not None]
            xs = [x for x in xs if not math.isnan(x)]
            if not xs or max(xs) - min(xs) < float(delta):
                return False
        return all(len(v) >= a.min for v in got.values())

    deadline = time.monotonic() + a.seconds
    next_cmd = 0.0
    while time.monotonic() < deadline and not holds():
        rclpy.spin_once(node, timeout_sec=0.02)
        if time.monotonic() < next_cmd:
            continue
        next_cmd = time.monotonic() + 0.1
        for pub, value in floats:
            if pub.get_subscription_count():
                pub.publish(Float64(data=value))
                sent += 1
        if joint_pub is not None and joint_pub.get_subscription_count():
            m = JointState(name=[n for n, _f, _v in joints])
            m.header.stamp = node.get_clock().now().to_msg()
            for field in ("position", "velocity", "effort"):
                setattr(m, field, [float(v) for _n, f, v in joints if f == field])
            joint_pub.publish(m)
            sent += 1
    linger = time.monotonic() + 0.3
    while time.monotonic() < linger:
        rclpy.spin_once(node, timeout_sec=0.02)
    print(
        json.dumps(
            {
                "start_ns": start_ns,
                "held": holds(),
                "sent": sent,
                "received": {k: v[-200:] for k, v in got.items()},
                "counts": {k: len(v) for k, v in got.items()},
                "topics": dict(node.get_topic_names_and_types()),
                "nodes": [n for n, _ns in node.get_node_names_and_namespaces()],
            }
        ),
        flush=True,
    )
    node.destroy_node()
    rclpy.shutdown()


if __name__ == "__main__":
    main()
