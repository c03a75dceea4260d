"""The Foxglove live view: a plain WebSocket client (websockets, foxglove.sdk.v1 subprotocol)
sees every topic advertised with its ros2msg schema, subscribes, and decodes a CDR sample."""

from __future__ import annotations

import asyncio
import json
import struct
from typing import Any

import pytest
import websockets
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config
from missing_link.testing import wait_for


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


@pytest.mark.slow
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
        wait_for(lambda: states and states[-1].values == [25], 10)
        time.sleep(0.5)
        ch, payload, _topics = asyncio.run(_client(d.foxglove.url, "/thesis/servo"))  # type: ignore[attr-defined]
    ts = get_typestore(Stores.ROS2_JAZZY)
    ts.register(get_types_from_msg(ch["schema"].split("=" * 80)[0], ch["schemaName"]))
    assert list(ts.deserialize_cdr(payload, ch["schemaName"]).values) == [25]


def listening() -> set[str]:
    """Every socket this process listens on: TCP ports and unix socket inodes."""
    import os

    mine = set()
    for fd in os.listdir("/proc/self/fd"):
        try:
            target = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            continue
        if target.startswith("socket:["):
            mine.add(target[8:-1])
    out = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        with open(table) as f:
            for row in f.read().splitlines()[1:]:
                col = row.split()
                if col[3] == "0A" and col[9] in mine:  # LISTEN
                    out.add(f"tcp:{int(col[1].rsplit(':', 1)[1], 16)}")
    with open("/proc/net/unix") as f:
        for row in f.read().splitlines()[1:]:
            col = row.split()
            if int(col[3], 16) & 0x10000 and col[6] in mine:  # __SO_ACCEPTCON: listening
                out.add(f"unix:{col[6]}")
    return out


def upgrade(port: int, origin: str | None, agent: str) -> int:
    """A WebSocket upgrade by hand (a client library refuses to send control characters in a
    header): the HTTP status of the answer."""
    import base64
    import os
    import socket

    lines = [
        "GET / HTTP/1.1", f"Host: 127.0.0.1:{port}", "Upgrade: websocket",
        "Connection: Upgrade", f"Sec-WebSocket-Key: {base64.b64encode(os.urandom(16)).decode()}",
        "Sec-WebSocket-Version: 13", "Sec-WebSocket-Protocol: foxglove.sdk.v1",
        f"User-Agent: {agent}", *([f"Origin: {origin}"] if origin is not None else []),
    ]  # fmt: skip
    with socket.create_connection(("127.0.0.1", port), timeout=5) as s:
        s.sendall(("\r\n".join(lines) + "\r\n\r\n").encode())
        head = b""
        while b"\r\n" not in head:
            chunk = s.recv(1024)
            if not chunk:
                break
            head += chunk
    return int(head.split()[1]) if head else 0  # (0: closed without an answer)


def test_the_view_opens_one_listener_and_it_is_gated(caplog: Any) -> None:
    """The Foxglove SDK's server used to listen on a second port of its own, ungated: a page
    with ``Origin: http://evil.example`` got every channel there.  Every listener the view
    opens refuses that origin, and what a client chose (its origin, its name) reaches the log
    only cleaned."""
    import logging

    from missing_link.publishers.foxglove import FoxglovePublisher

    before = listening()
    fox = FoxglovePublisher({"port": 0})
    try:
        opened = listening() - before
        assert opened == {f"tcp:{fox.port}"}, opened

        with caplog.at_level(logging.WARNING):
            for sock in opened:
                port = int(sock.split(":")[1])
                forged = "missing-link: error: forged\x1b[31m"
                assert upgrade(port, "http://evil.example", "a-browser") == 403
                assert upgrade(port, "http://evil.example", forged) in (0, 400)
                assert upgrade(port, "http://evil.example\x1b[2J", "a-browser") in (0, 400)
                assert upgrade(port, None, "a-script") == 101  # (a native client: admitted)
        assert fox.status()["origins_refused"] >= len(opened)
        logged = "\n".join(r.getMessage() for r in caplog.records)
        assert "evil.example" in logged and "\x1b" not in logged and "forged" not in logged
    finally:
        fox.close()
    assert listening() == before  # (and nothing is left listening)


def test_subscriptions_slow_clients_and_what_a_client_may_say() -> None:
    """The view's own protocol server: a client gets only what it subscribed to, until it
    unsubscribes; a client that does not read loses the oldest data (counted), not the others'
    data and not the daemon's memory; malformed operations are dropped and counted."""
    import websockets

    from missing_link.publishers.foxglove_server import BACKLOG, LiveView

    view = LiveView("127.0.0.1", 0, [])
    a = view.add_channel("/a", "std_msgs/msg/Empty", "")
    b = view.add_channel("/b", "std_msgs/msg/Empty", "")
    url = f"ws://127.0.0.1:{view.port}"

    async def until(pred: Any) -> None:
        for _ in range(500):
            if pred():
                return
            await asyncio.sleep(0.02)
        raise AssertionError("the view did not take the operation")

    async def run() -> list[bytes]:
        async with (
            websockets.connect(url, subprotocols=["foxglove.websocket.v1"]) as ws,  # type: ignore[list-item]
            websockets.connect(
                url,
                max_queue=1,
                close_timeout=0.5,
                subprotocols=["foxglove.sdk.v1"],  # type: ignore[list-item]
            ) as idle,
        ):
            info = json.loads(await ws.recv())
            adv = json.loads(await ws.recv())
            assert info["op"] == "serverInfo" and ws.subprotocol == "foxglove.websocket.v1"
            assert [c["topic"] for c in adv["channels"]] == ["/a", "/b"]
            for bad in ('{"op": "subscribe", "subscriptions": [{"id": -1, "channelId": 1}]}',
                        '{"op": "subscribe", "subscriptions": "all"}',
                        '{"op": "unsubscribe", "subscriptionIds": [true]}',
                        '{"op": {}}', '{"op": ["subscribe"]}',  # (unhashable: no op, no bug)
                        "[" * 60_000):  # fmt: skip
                await ws.send(bad)
            sub = {"op": "subscribe", "subscriptions": [{"id": 5, "channelId": a}]}
            await ws.send(json.dumps(sub))
            await idle.recv()
            await idle.recv()
            await idle.send(
                json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": b}]})
            )
            await until(lambda: view.subscriptions == 2)
            for k in range(3 * BACKLOG):  # the idle client reads none of /b
                view.log(b, b"x" * 1000, k)
            view.log(a, b"first", 1)
            got = [await asyncio.wait_for(ws.recv(), 5)]
            await ws.send(json.dumps({"op": "unsubscribe", "subscriptionIds": [5]}))
            await until(lambda: view.subscriptions == 1)
            view.log(a, b"second", 2)
            view.log(b, b"not subscribed", 3)
            with pytest.raises(TimeoutError):
                got.append(await asyncio.wait_for(ws.recv(), 0.5))
            return got  # type: ignore[return-value]

    try:
        got = asyncio.run(run())
    finally:
        view.close()
    assert [(struct.unpack_from("<I", m, 1)[0], m[13:]) for m in got] == [(5, b"first")]
    assert view.dropped_messages == 6 and view.dropped >= BACKLOG
    assert view.faults.total == 0
