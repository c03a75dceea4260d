"""The web console against a hostile client (publishers/web_server.py, gate.py): the token is
taken at /login only, failed logins are limited per client address (a guesser locks out itself,
not the owner) in a bounded table, the Host check holds without TLS even with a token (DNS
rebinding), a page that never reads is closed, and absurd numbers are refused, not bugs."""

from __future__ import annotations

import asyncio
import base64
import http.client
import json
import os
import socket
from pathlib import Path
from typing import Any

import websockets

from missing_link.publishers.front_door import LoginLimiter
from missing_link.publishers.web import WebPublisher
from missing_link.publishers.web_server import MAX_QUEUE

from .helpers import wait_for
from .test_web import TOKEN, console


def _get(face: WebPublisher, path: str, headers: dict[str, str], source: str = "127.0.0.1") -> int:
    """GET ``path`` from the address ``source`` (any of 127/8 reaches the console)."""
    port = int(face.url.rsplit(":", 1)[1].strip("/"))
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10, source_address=(source, 0))
    try:
        conn.request("GET", "/" + path, headers=headers)
        r = conn.getresponse()
        body = r.read()
        if path == "session":
            return len(json.loads(body))  # (what it says: the same whatever is sent)
        return r.status
    finally:
        conn.close()


def _token_file(tmp_path: Path) -> str:
    tok = tmp_path / "token"
    tok.write_text(TOKEN)
    tok.chmod(0o600)
    return str(tok)


def test_the_token_is_taken_at_login_only(serve: Any, tmp_path: Path) -> None:
    with console(serve, token_file=_token_file(tmp_path)) as (_d, face):
        bearer = {"Authorization": f"Bearer {TOKEN}"}
        assert _get(face, "session", bearer) == 2  # no oracle: the right token is not looked at
        assert _get(face, "ws", bearer) not in (101, 200)  # (and a socket needs its session)
        assert _get(face, "login", bearer) == 200


def test_failed_logins_lock_out_the_guesser_not_the_owner(serve: Any, tmp_path: Path) -> None:
    with console(serve, token_file=_token_file(tmp_path)) as (_d, face):
        wrong = {"Authorization": "Bearer guess"}
        assert [_get(face, "login", wrong, "127.0.0.2") for _ in range(6)] == [401] * 5 + [429]
        right = {"Authorization": f"Bearer {TOKEN}"}
        assert _get(face, "login", right, "127.0.0.2") == 429  # (the guesser: even the right one)
        assert _get(face, "login", right) == 200  # the owner, from another address
        assert face.status()["logins_refused"] == 7  # (5 wrong, 2 held off)


def test_the_login_table_is_bounded_and_eviction_gives_no_tries() -> None:
    limits = LoginLimiter(failures=5, window_s=60.0, max_clients=100)
    for i in range(10_000):  # a guesser with 10,000 addresses
        limits.failed(f"10.0.{i >> 8}.{i & 255}", 1.0)
    assert len(limits) == 101  # 100 addresses and the one shared by the rest
    assert limits.allows("10.0.0.0", 2.0)  # (one failure of its own)
    # the rest share one entry: a new address cannot buy fresh tries while the flood lasts
    assert not limits.allows("10.0.99.99", 2.0) and not limits.allows("192.0.2.1", 2.0)
    # once the window ends, addresses get entries of their own again
    assert limits.allows("192.0.2.1", 61.5)
    for _ in range(5):
        limits.failed("192.0.2.1", 62.0)
    assert not limits.allows("192.0.2.1", 121.9) and limits.allows("192.0.2.1", 122.1)
    assert limits.allows("192.0.2.2", 63.0)
    assert len(limits) <= 101


def test_a_rebound_name_is_refused_without_tls_even_with_a_token(
    serve: Any, tmp_path: Path
) -> None:
    with console(serve, token_file=_token_file(tmp_path)) as (_d, face):
        port = face.url.rsplit(":", 1)[1].strip("/")
        rebound = {"Host": f"evil.example:{port}", "Origin": f"http://evil.example:{port}"}
        assert _get(face, "login", {**rebound, "Authorization": f"Bearer {TOKEN}"}) == 421
        assert face.status()["hosts_refused"] == 1


def _frame(text: str) -> bytes:
    """A client's WebSocket text frame (masked, as a client's must be)."""
    data = text.encode()
    assert len(data) < 65536
    head = bytes([0x81, 0x80 | 126]) + len(data).to_bytes(2, "big")
    mask = os.urandom(4)
    return head + mask + bytes(c ^ mask[i % 4] for i, c in enumerate(data))


def test_a_page_that_sends_and_never_reads_is_closed(serve: Any) -> None:
    """A client that never reads a byte after the handshake (a raw socket with a small
    receive buffer: a WebSocket library would read on its own) and sends operations whose
    replies are 4 KB each: the server's socket fills, its replies wait, and at ``MAX_QUEUE``
    the page is closed (counted), never more held for it."""
    with console(serve) as (_d, face):
        port = int(face.url.rsplit(":", 1)[1].strip("/"))
        msg = _frame(json.dumps({"op": "command", "id": 10**3999}))  # (replies carry the id)
        sock = socket.socket()
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # (before connect: the window)
        sock.settimeout(10)
        sock.connect(("127.0.0.1", port))
        sock.sendall(
            f"GET /ws HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\n"
            f"Connection: Upgrade\r\nSec-WebSocket-Key: {base64.b64encode(os.urandom(16)).decode()}"
            f"\r\nSec-WebSocket-Version: 13\r\nOrigin: {face.url.rstrip('/')}\r\n\r\n".encode()
        )
        head = b""
        while b"\r\n\r\n" not in head:
            head += sock.recv(1)  # (byte by byte: not one byte of the hello after it)
        assert head.startswith(b"HTTP/1.1 101"), head
        sent = 0
        try:
            while face.status()["pages_closed"] == 0 and sent < 20_000:
                sock.sendall(msg)
                sent += 1
                queued = [len(p.out) for p in list(face.server._pages)]
                assert max(queued, default=0) <= MAX_QUEUE + 1, queued
        except OSError:  # (the server closed it: reset, broken pipe, or a send that blocks)
            pass
        finally:
            sock.close()
        assert wait_for(lambda: face.status()["pages_closed"] == 1, 10), (sent, face.status())
        assert wait_for(lambda: face.status()["clients"] == 0, 10)
        assert face.faults.total == 0


def _replies(face: WebPublisher, ops: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Each of ``ops`` sent for board_b from a page of the console's own origin, and its reply."""
    url = face.url.replace("http", "ws") + "ws"

    async def go() -> list[dict[str, Any]]:
        out = []
        async with websockets.connect(
            url, additional_headers={"Origin": face.url.rstrip("/")}
        ) as ws:
            await ws.recv()
            for i, op in enumerate(ops):
                await ws.send(json.dumps({"id": i, "board": "board_b", **op}))
                while (m := json.loads(await asyncio.wait_for(ws.recv(), 10)))["op"] != "reply":
                    pass
                out.append(m)
        return out

    return asyncio.run(go())


def test_huge_numbers_from_a_page_are_refused_not_bugs(serve: Any) -> None:
    with console(serve) as (_d, face):
        sets: list[object] = [10**400, "1_0", "\u0667", "7\x00", "1e999", 1e300, "0x10"]
        replies = _replies(face, [{"op": "config", "set": {"dist_ir.rate_hz": v}} for v in sets])
        assert [r["ok"] for r in replies] == [False] * len(sets), replies
        assert all("dist_ir.rate_hz" in r["text"] for r in replies), replies
        assert face.faults.total == 0


def test_save_and_erase_are_true_or_false(serve: Any) -> None:
    with console(serve) as (_d, face):
        ops: list[dict[str, Any]] = [{"op": "config", "set": {}, "save": [1]},
                                     {"op": "reset", "erase": "yes"}]  # fmt: skip
        replies = _replies(face, ops)
        assert [(r["ok"], r["text"]) for r in replies] == [
            (False, "save and erase: true or false")
        ] * 2, replies
