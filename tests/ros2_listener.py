"""An independent ROS 2 (rmw_zenoh format) consumer: plain zenoh + rosbags, no missing_link code.

Prints one JSON object per line: {"sample": ...} for each message on --topic, then {"graph":
[liveliness keys]}, then {"done": true}.  With --command it also publishes that message type's
values on a command topic, as a ROS 2 node would.  With --history it subscribes as a
transient-local rmw_zenoh subscriber does (zenoh's AdvancedSubscriber asking late-detected
publishers for their cached samples), so it gets a state published before it started.
"""

from __future__ import annotations

import argparse
import json
import os
import queue
import struct
import sys
import time

import zenoh
from rosbags.typesys import Stores, get_types_from_msg, get_typestore


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--connect", help="endpoint (default: the --config file's)")
    ap.add_argument("--config", help="a native Zenoh config file (TLS certificates)")
    ap.add_argument("--mode", default="peer")
    ap.add_argument("--topic", required=True)
    ap.add_argument("--type", required=True)
    ap.add_argument("--msgdef", required=True)
    ap.add_argument("--count", type=int, default=10)
    ap.add_argument("--timeout", type=float, default=20)
    ap.add_argument("--command", help="command topic to publish on")
    ap.add_argument("--command-type")
    ap.add_argument("--command-msgdef")
    ap.add_argument("--command-value", type=int)
    ap.add_argument("--command-dtype", default="int8", help="numpy type of the values array")
    ap.add_argument("--command-count", type=int, default=5)
    ap.add_argument(
        "--command-at-ms", type=float, help="a timed command: times[0] = now + this (a host time)"
    )
    ap.add_argument("--history", action="store_true", help="get cached samples (late joiner)")
    a = ap.parse_args()

    ts = get_typestore(Stores.ROS2_JAZZY)
    ts.register(get_types_from_msg(a.msgdef.replace("\\n", "\n"), a.type))
    pkg, _, name = a.type.split("/")
    key = f"0/{a.topic.lstrip('/')}/{pkg}::msg::dds_::{name}_/{ts.hash_rihs01(a.type)}"

    cfg = zenoh.Config.from_file(a.config) if a.config else zenoh.Config()
    if a.connect or not a.config:
        cfg.insert_json5("mode", json.dumps(a.mode))
        cfg.insert_json5("connect/endpoints", json.dumps([a.connect]))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    got: queue.Queue[tuple[str, bytes, bytes | None, int]] = queue.Queue()
    with zenoh.open(cfg) as session:

        def on_sample(s: zenoh.Sample) -> None:
            att = bytes(s.attachment) if s.attachment is not None else None
            got.put((str(s.key_expr), bytes(s.payload), att, time.time_ns()))

        if a.history:
            from zenoh.ext import HistoryConfig, declare_advanced_subscriber

            sub = declare_advanced_subscriber(
                session, key, on_sample, history=HistoryConfig(detect_late_publishers=True)
            )
        else:
            sub = session.declare_subscriber("0/**", on_sample)
        cmd_pub = None
        if a.command:
            ts.register(get_types_from_msg(a.command_msgdef.replace("\\n", "\n"), a.command_type))
            cpkg, _, cname = a.command_type.split("/")
            ckey = (
                f"0/{a.command.lstrip('/')}/{cpkg}::msg::dds_::{cname}_/"
                f"{ts.hash_rihs01(a.command_type)}"
            )
            cmd_pub = session.declare_publisher(ckey)
        n = 0
        deadline = time.monotonic() + a.timeout
        while n < a.count and time.monotonic() < deadline:
            try:
                k, payload, att, rx_ns = got.get(timeout=0.5)
            except queue.Empty:
                continue
            if k != key:
                continue
            msg = ts.deserialize_cdr(payload, a.type)
            seq, src_ns, gid_len = struct.unpack("<qqB", att[:17]) if att else (0, 0, 0)
            out = {
                "key": k,
                "encap": payload[:4].hex(),
                "values": [int(v) for v in msg.values],
                "times": [t.sec * 1_000_000_000 + t.nanosec for t in msg.times],
                "attachment_len": len(att) if att else 0,
                "seq": seq,
                "source_ns": src_ns,
                "gid_len": gid_len,
                "gid": att[17:33].hex() if att else "",
                "rx_ns": rx_ns,
            }
            print(json.dumps({"sample": out}), flush=True)
            n += 1
        graph = [str(r.ok.key_expr) for r in session.liveliness().get("@ros2_lv/**") if r.ok]
        print(json.dumps({"graph": graph}), flush=True)
        if cmd_pub is not None:
            cls = ts.types[a.command_type]
            import numpy as np

            Time = ts.types["builtin_interfaces/msg/Time"]
            at = 0 if a.command_at_ms is None else time.time_ns() + int(a.command_at_ms * 1e6)
            stamp = Time(sec=at // 10**9, nanosec=at % 10**9)
            values = np.array([a.command_value], getattr(np, a.command_dtype))
            msg = cls(times=[stamp], values=values)
            cdr = bytes(ts.serialize_cdr(msg, a.command_type))
            print(json.dumps({"command_at_ns": at}), flush=True)
            gid = os.urandom(16)
            for i in range(a.command_count):
                att = struct.pack("<qqB", i + 1, time.time_ns(), 16) + gid
                cmd_pub.put(cdr, attachment=att)
                time.sleep(0.1)
            cmd_pub.undeclare()
        sub.undeclare()
    print(json.dumps({"done": True}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
