"""The web console against a hostile client (publishers/web_server.py, gate.py): the token is
taken at /login only, failed logins are limited per client address (a guesser locks out itself,
not the owner) in a bounded table, the Host check holds without TLS even with a token (DNS
rebinding), a page that never reads is closed, and absurd numbers are refused, not bugs."""

from __future__ import annotations

import asyncio
import http.client
import json
import socket
from pathlib import Path
from typing import Any

import websockets

from missing_link.publishers.gate import LoginLimiter
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
            return 1 if json.loads(body)["authenticated"] else 0
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
        assert _get(face, "session", bearer) == 0  # no oracle: the right token is not looked at
        assert _get(face, "ws", bearer) == 401
        assert _get(face, "login", bearer) == 204


def test_failed_logins_lock_out_the_guesser_not_the_owner(serve: Any, tmp_path: Path) -> None:
    with console(serve, token_file=_token_file(tmp_path)) as (_d, face):
        wrong = {"Authorization": "Bearer guess"}
        assert [_get(face, "login", wrong, "127.0.0.2") for _ in range(6)] == [401] * 5 + [429]
        right = {"Authorization": f"Bearer {TOKEN}"}
        assert _get(face, "login", right, "127.0.0.2") == 429  # (the guesser: even the right one)
        assert _get(face, "login", right) == 204  # the owner, from another address
        assert face.status()["logins_refused"] == 7  # (5 wrong, 2 held off)


def test_the_login_table_is_bounded() -> None:
    limits = LoginLimiter(failures=5, window_s=60.0, max_clients=100)
    for i in range(10_000):
        limits.failed(f"10.0.{i >> 8}.{i & 255}", 1.0)
    assert len(limits) == 100
    assert limits.allows("10.0.0.0", 2.0)  # (the first went first)
    for _ in range(5):
        limits.failed("192.0.2.1", 3.0)
    assert not limits.allows("192.0.2.1", 62.9) and limits.allows("192.0.2.1", 63.1)
    assert limits.allows("192.0.2.2", 4.0)


def test_a_rebound_name_is_refused_without_tls_even_with_a_token(
    serve: Any, tmp_path: Path
) -> None:
    with console(serve, token_file=_token_file(tmp_path)) as (_d, face):
        port = face.url.rsplit(":", 1)[1].strip("/")
        rebound = {"Host": f"evil.example:{port}", "Origin": f"http://evil.example:{port}"}
        assert _get(face, "login", {**rebound, "Authorization": f"Bearer {TOKEN}"}) == 421
        assert face.status()["hosts_refused"] == 1


def test_a_page_that_sends_and_never_reads_is_closed(serve: Any) -> None:
    with console(serve) as (_d, face):
        url = face.url.replace("http", "ws") + "ws"
        # each reply carries the page's id back: 4,000 digits make every reply 4 KB
        msg = json.dumps({"op": "command", "id": 10**3999})

        async def flood() -> int:
            sent = 0
            async with websockets.connect(url, additional_headers={"Origin": face.url.rstrip("/")},
                                          max_queue=1) as ws:  # fmt: skip
                sock = ws.transport.get_extra_info("socket")
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
                try:
                    while face.status()["pages_closed"] == 0 and sent < 20_000:
                        await ws.send(msg)
                        sent += 1
                        if sent % 100 == 0:
                            queued = [len(p.out) for p in list(face.server._pages)]
                            assert max(queued, default=0) <= MAX_QUEUE + 1, queued
                            await asyncio.sleep(0)
                except websockets.ConnectionClosed:
                    pass
                finally:
                    ws.transport.abort()  # (it never reads: no closing handshake to wait for)
            return sent

        sent = asyncio.run(flood())
        assert wait_for(lambda: face.status()["pages_closed"] == 1, 10), (sent, face.status())
        assert wait_for(lambda: face.status()["clients"] == 0, 10)
        assert face.faults.total == 0


def test_huge_numbers_from_a_page_are_refused_not_bugs(serve: Any) -> None:
    with console(serve) as (_d, face):
        url = face.url.replace("http", "ws") + "ws"
        sets: list[object] = [10**400, "1_0", "\u0667", "7\x00", "1e999", 1e300, "0x10"]

        async def go() -> list[dict[str, Any]]:
            out = []
            async with websockets.connect(
                url, additional_headers={"Origin": face.url.rstrip("/")}
            ) as ws:
                await ws.recv()
                for i, v in enumerate(sets):
                    await ws.send(json.dumps({"op": "config", "id": i, "board": "board_b",
                                              "set": {"dist_ir.rate_hz": v}}))  # fmt: skip
                    while (m := json.loads(await asyncio.wait_for(ws.recv(), 10)))["op"] != "reply":
                        pass
                    out.append(m)
            return out

        replies = asyncio.run(go())
        assert [r["ok"] for r in replies] == [False] * len(sets), replies
        assert all("dist_ir.rate_hz" in r["text"] for r in replies), replies
        assert face.faults.total == 0


def test_save_and_erase_are_true_or_false(serve: Any) -> None:
    with console(serve) as (_d, face):
        url = face.url.replace("http", "ws") + "ws"
        ops: list[dict[str, Any]] = [{"op": "config", "set": {}, "save": [1]},
                                     {"op": "reset", "erase": "yes"}]  # fmt: skip

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

        replies = asyncio.run(go())
        assert [(r["ok"], r["text"]) for r in replies] == [
            (False, "save and erase: true or false")
        ] * 2, replies
