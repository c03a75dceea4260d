"""The Foxglove live view: a plain WebSocket client (websockets, foxglove.sdk.v1 subprotocol)
sees every topic advertised with its ros2msg schema, subscribes, and decodes a CDR sample."""

from __future__ import annotations

import asyncio
import json
import struct
from typing import Any

import websockets
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config


async def _client(url: str, topic: str) -> tuple[dict, bytes, list[str]]:
    async with websockets.connect(url, subprotocols=["foxglove.sdk.v1"]) as ws:
        channels: dict[str, dict] = {}
        while topic not in channels:
            msg = await asyncio.wait_for(ws.recv(), 10)
            if isinstance(msg, str):
                m = json.loads(msg)
                if m.get("op") == "advertise":
                    channels.update({c["topic"]: c for c in m["channels"]})
        ch = channels[topic]
        await ws.send(
            json.dumps({"op": "subscribe", "subscriptions": [{"id": 7, "channelId": ch["id"]}]})
        )
        while True:
            msg = await asyncio.wait_for(ws.recv(), 10)
            if isinstance(msg, bytes) and msg[0] == 0x01:
                sub_id, _log_time = struct.unpack_from("<IQ", msg, 1)
                assert sub_id == 7
                return ch, msg[13:], sorted(channels)


def foxglove_daemon(url: str) -> Daemon:
    """A daemon with the Foxglove publisher on a free loopback port (its url: .foxglove.url)."""
    cfg = Config(
        boards=[BoardSpec(url)],
        publishers=["bus", "foxglove"],
        publisher_options={"foxglove": {"port": 0}},
    )
    d = Daemon(cfg)
    d.foxglove = next(p for p in d.publishers if p.name == "foxglove")  # type: ignore[attr-defined]
    return d


def test_websocket_client_decodes_a_sample(serve) -> None:  # type: ignore[no-untyped-def]
    server = serve("thesis", "tcp://127.0.0.1:0")
    with foxglove_daemon(server.url) as d:
        assert d.wait_until_up(10)
        fox = d.foxglove  # type: ignore[attr-defined]
        assert fox.url.startswith("ws://127.0.0.1:")
        ch, payload, topics = asyncio.run(_client(fox.url, "/thesis/dist_ir"))
    assert {"/thesis/quad", "/thesis/dist_ir", "/thesis/dist_ir/range", "/diagnostics"} <= set(
        topics
    )
    assert ch["encoding"] == "cdr" and ch["schemaEncoding"] == "ros2msg"
    assert ch["schemaName"] == "missing_link_msgs/msg/DistIr"
    ts = get_typestore(Stores.ROS2_JAZZY)
    ts.register(get_types_from_msg(ch["schema"].split("=" * 80)[0], ch["schemaName"]))
    msg = ts.deserialize_cdr(payload, ch["schemaName"])
    assert len(msg.values) == 8 and len(msg.times) == 8
    assert any(t.sec > 1_600_000_000 for t in msg.times)  # host time (CLOCK_REALTIME) stamps


def test_official_foxglove_client_decodes_with_the_schema(serve) -> None:  # type: ignore[no-untyped-def]
    """The official protocol client (@foxglove/ws-protocol, under node) subscribes and decodes a
    DistIr message with the advertised ros2msg schema (@foxglove/rosmsg2-serialization)."""
    import shutil
    import subprocess
    from pathlib import Path

    node = shutil.which("node")
    assert node, "node is installed by make test (scripts/system-deps.sh)"
    server = serve("thesis", "tcp://127.0.0.1:0")
    with foxglove_daemon(server.url) as d:
        assert d.wait_until_up(10)
        fox = d.foxglove  # type: ignore[attr-defined]
        here = Path(__file__).parent
        r = subprocess.run(
            [node, str(here / "foxglove_client.mjs"), fox.url, "/thesis/dist_ir"],
            capture_output=True,
            text=True,
            timeout=60,
            cwd=here.parent,
        )
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert out["protocol"] == "foxglove.sdk.v1"
    assert out["channel"] == {
        "encoding": "cdr",
        "schemaName": "missing_link_msgs/msg/DistIr",
        "schemaEncoding": "ros2msg",
    }
    assert len(out["values"]) == 8 and len(out["times_sec"]) == 8
    assert any(s > 1_600_000_000 for s in out["times_sec"])
    assert int(out["log_time_ns"]) > 1_600_000_000 * 10**9
    assert "/thesis/dist_ir/range" in out["topics"] and "/diagnostics" in out["topics"]


def test_a_late_client_gets_the_actuators_state(serve) -> None:  # type: ignore[no-untyped-def]
    """The servo reports its state only when it changes; a client that connects after it
    settled still gets it (sent again with every /diagnostics round)."""
    import time

    server = serve("thesis", "tcp://127.0.0.1:0")
    with foxglove_daemon(server.url) as d:
        assert d.wait_until_up(10)
        states: list[Any] = []
        d.subscribe("/thesis/servo", states.append, queue=0)
        d.send("/thesis/servo/cmd", 25)
        deadline = time.monotonic() + 10
        while not (states and states[-1].values == [25]) and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.5)
        ch, payload, _topics = asyncio.run(_client(d.foxglove.url, "/thesis/servo"))  # type: ignore[attr-defined]
    ts = get_typestore(Stores.ROS2_JAZZY)
    ts.register(get_types_from_msg(ch["schema"].split("=" * 80)[0], ch["schemaName"]))
    assert list(ts.deserialize_cdr(payload, ch["schemaName"]).values) == [25]
