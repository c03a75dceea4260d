"""An independent ROS 2 node (rclpy only; nothing from missing_link): subscribes to the topics it
is given, reads the ROS graph, optionally publishes commands, and prints one JSON object.

    python ros2_rclpy_listener.py --seconds 8 \
        --sub /thesis/dist_ir/range=sensor_msgs/msg/Range \
        --sub /diagnostics=diagnostic_msgs/msg/DiagnosticArray \
        [--sensor-qos] [--cmd /thesis/servo/cmd=missing_link_msgs/msg/Servo=40] \
        [--until-text /rosout=tof]

A command value VALUE@MS is a timed command: its times[0] is the host time MS ms after it is
sent (CLOCK_REALTIME); the times sent are printed ("sent_at_ns").  It waits until every
subscribed topic delivered at least --min messages (or --seconds pass)."""

from __future__ import annotations

import argparse
import importlib
import json
import time
from typing import Any

import rclpy
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data


def msg_class(type_name: str) -> Any:
    pkg, _msg, name = type_name.split("/")
    return getattr(importlib.import_module(f"{pkg}.msg"), name)


def summarise(msg: Any) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for field in msg.get_fields_and_field_types():
        v = getattr(msg, field)
        if field == "header":
            out["stamp_ns"] = v.stamp.sec * 10**9 + v.stamp.nanosec
            out["frame_id"] = v.frame_id
        elif field == "times":
            out["times_ns"] = [t.sec * 10**9 + t.nanosec for t in v]
        elif field == "status":
            out["status"] = [
                {
                    "name": s.name,
                    "level": int.from_bytes(s.level, "little")
                    if isinstance(s.level, bytes)
                    else int(s.level),
                    "message": s.message,
                }
                for s in v
            ]
        elif isinstance(v, (int, float, str)):
            out[field] = v
        elif hasattr(v, "__len__") and field in ("values", "position", "name"):
            out[field] = [x if isinstance(x, (int, float, str)) else float(x) for x in v]
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--min", type=int, default=3)
    ap.add_argument("--sub", action="append", default=[])
    ap.add_argument("--cmd", action="append", default=[])
    ap.add_argument("--sensor-qos", action="store_true")
    ap.add_argument(
        "--transient-local", action="store_true", help="ask for what was published before"
    )
    ap.add_argument("--depth", type=int, default=1, help="history kept (--transient-local)")
    ap.add_argument("--until-value", help="TOPIC=VALUE: also wait until TOPIC carries VALUE")
    ap.add_argument("--min-sent", type=int, default=0, help="also wait until N commands went")
    ap.add_argument(
        "--until-text", help="TOPIC=TEXT: also wait until a string field on TOPIC holds TEXT"
    )
    a = ap.parse_args()
    rclpy.init()
    node = rclpy.create_node("independent_listener")
    got: dict[str, list[dict[str, Any]]] = {}
    for spec in a.sub:
        topic, type_name = spec.split("=")
        got[topic] = []
        qos: Any = qos_profile_sensor_data if a.sensor_qos else 10
        if a.transient_local:
            qos = QoSProfile(
                depth=a.depth,
                reliability=ReliabilityPolicy.RELIABLE,
                durability=DurabilityPolicy.TRANSIENT_LOCAL,
            )
        node.create_subscription(
            msg_class(type_name), topic, lambda m, t=topic: got[t].append(summarise(m)), qos
        )
    pubs = []
    sent_at: list[int] = []
    sent = 0
    for spec in a.cmd:
        topic, type_name, value = spec.split("=")
        pubs.append((node.create_publisher(msg_class(type_name), topic, 10), type_name, value))
    Time = importlib.import_module("builtin_interfaces.msg").Time
    wait_topic, wait_value = a.until_value.split("=") if a.until_value else (None, None)
    text_topic, wait_text = a.until_text.split("=", 1) if a.until_text else (None, "")
    deadline = time.monotonic() + a.seconds
    next_cmd = 0.0
    while time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
        if pubs and time.monotonic() >= next_cmd:
            next_cmd = time.monotonic() + 0.5
            for pub, type_name, value in pubs:
                if pub.get_subscription_count() == 0:
                    continue  # (not matched yet: DDS would drop it)
                m = msg_class(type_name)()
                v, _, ahead_ms = value.partition("@")
                if hasattr(m, "data"):  # (a standard command: std_msgs/msg/Float64, SI)
                    m.data = float(v)
                else:
                    m.values = [int(v)]
                if ahead_ms:
                    at = time.time_ns() + int(float(ahead_ms) * 1e6)
                    m.times = [Time(sec=at // 10**9, nanosec=at % 10**9)]
                    sent_at.append(at)
                pub.publish(m)
                sent += 1
        enough = all(len(v) >= a.min for v in got.values()) and sent >= a.min_sent
        if wait_topic is not None:
            enough = enough and any(
                wait_value is not None and float(wait_value) in s.get("values", [])
                for s in got.get(wait_topic, [])
            )
        if text_topic is not None:
            enough = enough and any(
                wait_text in v
                for s in got.get(text_topic, [])
                for v in s.values()
                if isinstance(v, str)
            )
        if enough:
            linger = time.monotonic() + 0.5  # what was sent alongside arrives too
            while time.monotonic() < linger:
                rclpy.spin_once(node, timeout_sec=0.05)
            break
    topics = {name: types for name, types in node.get_topic_names_and_types()}
    nodes = node.get_node_names_and_namespaces()
    print(
        json.dumps(
            {
                "received": {k: v[-100:] for k, v in got.items()},
                "counts": {k: len(v) for k, v in got.items()},
                "topics": topics,
                "nodes": [n for n, _ns in nodes],
                "sent_at_ns": sent_at,
                "sent": sent,
            }
        ),
        flush=True,
    )
    node.destroy_node()
    rclpy.shutdown()


if __name__ == "__main__":
    main()
