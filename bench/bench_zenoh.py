"""Publish -> remote subscriber through Zenoh (rmw_zenoh format) and through rclpy (ROS 2 Kilted,
rmw_fastrtps_cpp, from the wheels in .venv-ros2), against the in-process bus.

The daemon side is the real ``ZenohPublisher`` fed with thesis-format updates (8 x uint16, as
the IR board sends); the subscriber is another process (plain zenoh, no missing_link code) on
loopback, directly (peer to peer) and through a router process.  Latency: the publisher puts
its CLOCK_MONOTONIC send time in the message; the subscriber stamps arrival on the same clock.
Rate: a burst of messages, counted at the subscriber.  The publisher never blocks the board's
reader thread (zenoh's default congestion control drops), so a burst faster than the link
shows up as "delivered" below 100 %.  Reference in the same run: the same
updates delivered to a subscriber callback on the in-process bus.

The ROS 2 row runs both ends in .venv-ros2 (bench/ros2_endpoint.py): missing-link's
Ros2Publisher and a plain rclpy subscriber, Fast DDS on loopback only (tests/fastdds_loopback.xml).

    .venv/bin/python bench/bench_zenoh.py [--messages 20000]
"""

from __future__ import annotations

import argparse
import socket
import subprocess
import sys
import textwrap
import time

import numpy as np

from _pacing import pace  # bench/ is on sys.path when a script here runs
from missing_link.descriptors import parse_transds
from missing_link.publishers.bus import Bus
from missing_link.publishers.zenoh import ZenohPublisher
from missing_link.topics import Topic, Update

SUB = textwrap.dedent(
    """
    import json, struct, sys, threading, time, zenoh
    connect, mode, n = sys.argv[1], sys.argv[2], int(sys.argv[3])
    cfg = zenoh.Config()
    cfg.insert_json5("mode", json.dumps(mode))
    cfg.insert_json5("connect/endpoints", json.dumps([connect]))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    lat, count, first, last = [], [0], [0], [0]
    done = threading.Event()
    def on(s):
        now = time.monotonic_ns()
        p = bytes(s.payload)
        sent, = struct.unpack_from("<q", p, len(p) - 8)
        if count[0] == 0: first[0] = now
        count[0] += 1
        last[0] = now
        lat.append(now - sent)
        if count[0] >= n: done.set()
    with zenoh.open(cfg) as z:
        sub = z.declare_subscriber("0/bench/**", on)
        print("READY", flush=True)
        start = time.monotonic_ns()
        while not done.wait(0.5):  # stop at n, or after 3 s without a message
            quiet = time.monotonic_ns() - max(last[0], start) > 3e9
            if quiet and (count[0] or time.monotonic_ns() - start > 60e9):
                break
        sub.undeclare()
    print(json.dumps({"count": count[0], "lat": lat, "span": last[0] - first[0]}), flush=True)
    """
)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def topic() -> Topic:
    t = parse_transds("transds/1\nbench,1,x,X,8,uint16_t,0\n", "bench")[0]
    return Topic.for_transducer("/bench/ir", "bench", t, "missing_link_msgs")


class Stamped(Update):
    """An update whose CDR carries the send time in its last 8 bytes (after the values)."""

    __slots__ = ()

    @property
    def cdr(self) -> bytes:
        return super().cdr + time.monotonic_ns().to_bytes(8, "little", signed=True)


def make_updates(tp: Topic, n: int) -> list[Update]:
    now = time.time_ns()
    return [Stamped(tp, [i] * 8, [now + i] * 8, [i & 0xFFFF] * 8, i & 0xFF, 0, 0) for i in range(n)]


def run_remote(n: int, paced_hz: float | None, via_router: bool) -> dict[str, float]:
    port = free_port()
    router = None
    opts: dict[str, object]
    if via_router:
        router = subprocess.Popen(
            [sys.executable, "-m", "missing_link", "router", "--listen", f"tcp/127.0.0.1:{port}"],
            stdout=subprocess.PIPE,
            text=True,
        )
        assert router.stdout is not None and router.stdout.readline().startswith("READY")
        opts = {"connect": [f"tcp/127.0.0.1:{port}"], "listen": []}
        sub_args = [f"tcp/127.0.0.1:{port}", "client"]
    else:
        opts = {"listen": [f"tcp/127.0.0.1:{port}"], "connect": []}
        sub_args = [f"tcp/127.0.0.1:{port}", "peer"]
    pub = ZenohPublisher(opts)
    try:
        tp = topic()
        pub.add_topic(tp)
        sub = subprocess.Popen(
            [sys.executable, "-c", SUB, *sub_args, str(n)], stdout=subprocess.PIPE, text=True
        )
        assert sub.stdout is not None and sub.stdout.readline().startswith("READY")
        time.sleep(1.0)  # let the subscription propagate
        updates = make_updates(tp, n)
        t0 = time.perf_counter()
        for i, u in enumerate(updates):
            if paced_hz:
                target = t0 + i / paced_hz
                pace(target)
            pub.publish(u)
        sent_s = time.perf_counter() - t0
        out, _ = sub.communicate(timeout=120)
    finally:
        pub.close()
        if router is not None:
            router.terminate()
            router.wait(10)
    import json

    res = json.loads(out.strip().splitlines()[-1])
    lat = np.array(res["lat"]) / 1000
    return {
        "received": res["count"],
        "sent_per_s": n / sent_s,
        "recv_per_s": res["count"] / (res["span"] / 1e9) if res["span"] else 0.0,
        "p50": float(np.percentile(lat, 50)),
        "p99": float(np.percentile(lat, 99)),
    }


def run_ros2(n: int, paced_hz: float | None) -> dict[str, float]:
    import json
    import os
    import random
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    py = os.environ.get("ML_ROS2_PYTHON") or str(root / ".venv-ros2" / "bin" / "python")
    if not Path(py).exists():
        raise SystemExit(f"{py} missing: make ros2")
    env = {k: v for k, v in os.environ.items() if not k.startswith(("ROS_", "_ROS_WHEELS"))}
    env.update(
        ROS_DOMAIN_ID=str(random.randrange(1, 200)),
        FASTDDS_DEFAULT_PROFILES_FILE=str(root / "tests" / "fastdds_loopback.xml"),
    )
    script = str(root / "bench" / "ros2_endpoint.py")
    pub = subprocess.Popen(
        [py, script, "pub", str(n), str(paced_hz or 0)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        env=env,
    )
    assert pub.stdout is not None and pub.stdin is not None
    assert pub.stdout.readline().startswith("READY")
    sub = subprocess.Popen([py, script, "sub", str(n)], stdout=subprocess.PIPE, text=True, env=env)
    assert sub.stdout is not None and sub.stdout.readline().startswith("READY")
    time.sleep(1.0)  # let matching finish both ways
    pub.stdin.write("go\n")
    pub.stdin.flush()
    out, _ = sub.communicate(timeout=180)
    pout, _ = pub.communicate(timeout=60)
    res = json.loads(out.strip().splitlines()[-1])
    sent = json.loads(pout.strip().splitlines()[-1])
    lat = np.array(res["lat"]) / 1000
    return {
        "received": res["count"],
        "sent_per_s": sent["sent_per_s"],
        "recv_per_s": res["count"] / res["span"] if res["span"] else 0.0,
        "p50": float(np.percentile(lat, 50)),
        "p99": float(np.percentile(lat, 99)),
    }


def run_bus(n: int, paced_hz: float | None, queue: int = 0) -> dict[str, float]:
    bus = Bus()
    tp = topic()
    bus.add_topic(tp)
    lat: list[int] = []
    sub = bus.subscribe(
        "/bench/ir", lambda u: lat.append(time.monotonic_ns() - u.recv_ns), queue=queue
    )
    t0 = time.perf_counter()
    now = time.time_ns()
    for i in range(n):
        if paced_hz:
            target = t0 + i / paced_hz
            pace(target)
        bus.publish(
            Update.build(
                topic=tp,
                board_us=[i] * 8,
                host_ns=[now] * 8,
                values=[i] * 8,
                seq=0,
                lost=0,
                recv_ns=time.monotonic_ns(),
            )
        )
    span = time.perf_counter() - t0
    deadline = time.monotonic() + 10
    while len(lat) + sub.dropped < n and time.monotonic() < deadline:
        time.sleep(0.01)  # the subscriber's own thread drains its queue
    bus.close()
    a = np.array(lat) / 1000
    return {
        "received": len(lat),
        "sent_per_s": n / span,
        "recv_per_s": n / span,
        "p50": float(np.percentile(a, 50)),
        "p99": float(np.percentile(a, 99)),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--messages", type=int, default=20000)
    ap.add_argument("--paced", type=int, default=2000, help="messages for the latency runs")
    a = ap.parse_args()
    print("| path | latency p50 µs (1 kHz) | p99 µs | burst msgs/s received | delivered |")
    print("|---|---|---|---|---|")
    rows = [
        ("in-process bus, inline callback (reference)", lambda p, n: run_bus(n, p)),
        ("in-process bus, subscriber thread (default)", lambda p, n: run_bus(n, p, 10_000)),
        ("zenoh peer -> subscriber process", lambda p, n: run_remote(n, p, False)),
        ("zenoh via router process", lambda p, n: run_remote(n, p, True)),
        ("ROS 2: rclpy publisher -> rclpy subscriber process", lambda p, n: run_ros2(n, p)),
    ]
    for name, fn in rows:
        lat = fn(1000.0, a.paced)
        burst = fn(None, a.messages)
        print(
            f"| {name} | {lat['p50']:.1f} | {lat['p99']:.1f} | {burst['recv_per_s']:,.0f}"
            f" | {burst['received']}/{a.messages} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
