"""An independent ROS 2 (rmw_zenoh format) consumer of standard types: plain zenoh + rosbags, no
missing_link code.  Reads every sample under the domain, checks each key's type hash against
rosbags' RIHS01 for its type, decodes the standard ones, and publishes standard commands
(std_msgs/msg/Float64, sensor_msgs/msg/JointState) with rmw_zenoh's attachment.  Prints one JSON
object: per topic the type, whether its hash matched, and the decoded messages (summarised).

    python zenoh_standard_listener.py --connect tcp/127.0.0.1:PORT --seconds 20 \
        --want /rig/imu/imu --float64 /rig/servo/command=0.5 --joint mast=position=3.14
"""

from __future__ import annotations

import argparse
import json
import os
import queue
import struct
import sys
import time
from typing import Any

import numpy as np
import zenoh
from rosbags.typesys import Stores, get_typestore

TS = get_typestore(Stores.ROS2_JAZZY)


def type_of(dds: str) -> str:
    """``sensor_msgs::msg::dds_::Imu_`` -> ``sensor_msgs/msg/Imu``."""
    pkg, kind, _dds, name = dds.split("::")
    return f"{pkg}/{kind}/{name.rstrip('_')}"


def summarise(msg: Any) -> Any:
    if hasattr(msg, "__msgtype__"):
        out = {}
        for k in msg.__dataclass_fields__:
            if k.isupper():
                continue  # (constants)
            v = getattr(msg, k)
            if k == "header":
                out["stamp_ns"] = v.stamp.sec * 10**9 + v.stamp.nanosec
                out["frame_id"] = v.frame_id
            else:
                out[k] = summarise(v)
        return out
    if isinstance(msg, np.ndarray):
        return [float(x) for x in msg]
    if isinstance(msg, list):
        return [summarise(x) for x in msg]
    return msg.item() if hasattr(msg, "item") else msg


def key_for(topic: str, type_name: str) -> str:
    pkg, kind, name = type_name.split("/")
    return f"0/{topic.lstrip('/')}/{pkg}::{kind}::dds_::{name}_/{TS.hash_rihs01(type_name)}"


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--connect", required=True)
    ap.add_argument("--seconds", type=float, default=20)
    ap.add_argument("--want", action="append", default=[], help="wait for this topic")
    ap.add_argument("--float64", action="append", default=[], help="TOPIC=VALUE")
    ap.add_argument("--joint", action="append", default=[], help="NAME=FIELD=VALUE")
    a = ap.parse_args()
    cfg = zenoh.Config()
    cfg.insert_json5("mode", '"peer"')
    cfg.insert_json5("connect/endpoints", json.dumps([a.connect]))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    got: queue.Queue[tuple[str, bytes, bytes | None]] = queue.Queue()
    topics: dict[str, dict[str, Any]] = {}
    gid = os.urandom(16)
    with zenoh.open(cfg) as session:
        sub = session.declare_subscriber(
            "0/**",
            lambda s: got.put((str(s.key_expr), bytes(s.payload),
                               bytes(s.attachment) if s.attachment is not None else None)),
        )  # fmt: skip
        pubs = []
        for spec in a.float64:
            topic, value = spec.split("=")
            msg = TS.types["std_msgs/msg/Float64"](data=float(value))
            cdr = bytes(TS.serialize_cdr(msg, "std_msgs/msg/Float64"))
            pubs.append((session.declare_publisher(key_for(topic, "std_msgs/msg/Float64")), cdr))
        if a.joint:
            J, H, T = (TS.types[t] for t in ("sensor_msgs/msg/JointState", "std_msgs/msg/Header",
                                              "builtin_interfaces/msg/Time"))  # fmt: skip
            parts = [s.split("=") for s in a.joint]
            fields = {
                f: np.array([float(v) for _n, g, v in parts if g == f], dtype=np.float64)
                for f in ("position", "velocity", "effort")
            }
            msg = J(header=H(stamp=T(sec=0, nanosec=0), frame_id=""),
                    name=[n for n, _g, _v in parts], **fields)  # fmt: skip
            cdr = bytes(TS.serialize_cdr(msg, "sensor_msgs/msg/JointState"))
            key = key_for("/joint_commands", "sensor_msgs/msg/JointState")
            pubs.append((session.declare_publisher(key), cdr))
        seq = 0
        deadline = time.monotonic() + a.seconds
        next_cmd = 0.0
        while time.monotonic() < deadline:
            if time.monotonic() >= next_cmd:
                next_cmd = time.monotonic() + 0.1
                for pub, cdr in pubs:
                    seq += 1
                    pub.put(cdr, attachment=struct.pack("<qqB", seq, time.time_ns(), 16) + gid)
            try:
                key, payload, att = got.get(timeout=0.05)
            except queue.Empty:
                continue
            _domain, rest = key.split("/", 1)
            *path, dds, hash_ = rest.split("/")
            topic = "/" + "/".join(path)
            type_name = type_of(dds)
            entry = topics.setdefault(topic, {"type": type_name, "messages": []})
            entry["hash_ok"] = type_name in TS.types and hash_ == TS.hash_rihs01(type_name)
            if not type_name.startswith("missing_link_msgs/") and type_name in TS.types:
                m = summarise(TS.deserialize_cdr(payload, type_name))
                src = struct.unpack("<q", att[8:16])[0] if att and len(att) == 33 else 0
                entry["messages"] = [*entry["messages"][-50:], {**m, "source_ns": src}]
            if all(topics.get(w, {}).get("messages") for w in a.want) and not pubs:
                break
        for pub, _cdr in pubs:
            pub.undeclare()
        sub.undeclare()
    print(json.dumps({"topics": topics}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
