"""The two ends of bench_zenoh.py's ROS 2 row, run in the ROS 2 environment (.venv-ros2):

    python ros2_endpoint.py pub N HZ   # missing-link's Ros2Publisher publishing N Range updates
    python ros2_endpoint.py sub N      # a plain rclpy subscriber (no missing_link code)

The publisher puts its CLOCK_MONOTONIC send time into header.stamp (patched into a Range CDR
template at send time, as cheap as the daemon's own path); the subscriber stamps arrival on the
same clock.  Both print one JSON line."""

from __future__ import annotations

import json
import struct
import sys
import time

from _pacing import pace  # bench/ is on sys.path when a script here runs


def pub(n: int, hz: float) -> None:
    from rosbags.typesys import Stores, get_typestore

    from missing_link.descriptors import parse_transds
    from missing_link.publishers.ros2 import Ros2Publisher
    from missing_link.topics import Topic, Update

    ts = get_typestore(Stores.ROS2_KILTED)
    T = ts.types
    rng = T["sensor_msgs/msg/Range"](
        header=T["std_msgs/msg/Header"](
            stamp=T["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id="bench/ir/0"
        ),
        radiation_type=1,
        field_of_view=0.1,
        min_range=0.2,
        max_range=1.5,
        range=0.5,
        variance=0.0,
    )
    template = bytearray(ts.serialize_cdr(rng, "sensor_msgs/msg/Range"))
    t = parse_transds("transds/1\nir,1,x,X,1,uint16_t,0\n", "bench")[0]
    text, _ = ts.generate_msgdef("sensor_msgs/msg/Range", ros_version=2)
    topic = Topic("/bench/ir/range", "bench", t, "sensor_msgs/msg/Range", text, None, True)
    p = Ros2Publisher({"node": "bench_pub"})
    p.add_topic(topic)
    print("READY", flush=True)
    sys.stdin.readline()  # the subscriber is up
    t0 = time.perf_counter()
    for i in range(n):
        if hz:
            target = t0 + i / hz
            pace(target)
        sec, nsec = divmod(time.monotonic_ns(), 1_000_000_000)
        struct.pack_into("<iI", template, 4, sec, nsec)
        p.publish(
            Update.build(
                topic=topic,
                board_us=[i],
                host_ns=[i],
                values=[500],
                seq=0,
                lost=0,
                recv_ns=0,
                cdr=bytes(template),
            )
        )
    sent_s = time.perf_counter() - t0
    time.sleep(1.0)
    p.close()
    print(json.dumps({"sent_per_s": n / sent_s}), flush=True)


def sub(n: int) -> None:
    import rclpy
    from sensor_msgs.msg import Range

    rclpy.init()
    node = rclpy.create_node("bench_sub")
    lat: list[int] = []
    stamps: list[int] = []

    def on(m: Range) -> None:
        now = time.monotonic_ns()
        lat.append(now - (m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec))
        stamps.append(now)

    node.create_subscription(Range, "/bench/ir/range", on, 10_000)
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline and node.count_publishers("/bench/ir/range") == 0:
        rclpy.spin_once(node, timeout_sec=0.05)
    print("READY", flush=True)
    quiet_since = time.monotonic()
    while len(lat) < n and time.monotonic() - quiet_since < 3.0:
        before = len(lat)
        rclpy.spin_once(node, timeout_sec=0.05)
        if len(lat) != before:
            quiet_since = time.monotonic()
    span = (stamps[-1] - stamps[0]) / 1e9 if len(stamps) > 1 else 0.0
    print(json.dumps({"count": len(lat), "lat": lat, "span": span}), flush=True)
    rclpy.shutdown()


if __name__ == "__main__":
    if sys.argv[1] == "pub":
        pub(int(sys.argv[2]), float(sys.argv[3]))
    else:
        sub(int(sys.argv[2]))
