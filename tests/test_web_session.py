"""The web console's session (issue 43.2, publishers/web_auth.py) and its commands at the edge of
their type (issue 43.1), against plain WebSocket and HTTP clients: a login answers a secret and
sets no cookie; a socket is a session's only when its first message is a secret made for the
socket's origin; a command the actuator's type cannot hold (a JSON number beyond a double is
infinity once parsed) is refused and counted, and the board's session goes on.  In a real
browser, with a hostile page on another port: tests/test_web_origin.py."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path
from typing import Any

import websockets

from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config
from missing_link.publishers.web import WebPublisher

from .helpers import wait_for
from .test_command_edges import _board
from .test_web import TOKEN, _get, console, origin
from .test_web_guard import _token_file


def login(face: WebPublisher, **headers: str) -> str:
    status, got, body = _get(face.url + "login", {"Authorization": f"Bearer {TOKEN}", **headers})
    assert status == 200 and "Set-Cookie" not in got, (status, dict(got))  # (no cookie: ports)
    return str(json.loads(body)["session"])


def opens(face: WebPublisher, first: str | None, origin_header: str | None) -> str:
    """A socket with ``origin_header`` whose first message is ``first``: "hello", or how it
    was closed."""

    async def go() -> str:
        url = face.url.replace("http", "ws") + "ws"
        headers = {"Origin": origin_header} if origin_header else {}
        try:
            async with websockets.connect(url, additional_headers=headers) as ws:
                if first is not None:
                    await ws.send(first)
                return str(json.loads(await asyncio.wait_for(ws.recv(), 10))["op"])
        except websockets.ConnectionClosed as e:
            return f"closed {e.rcvd.code if e.rcvd else '?'}"
        except websockets.InvalidStatus as e:
            return f"refused {e.response.status_code}"

    return asyncio.run(go())


def auth(sid: str) -> str:
    return json.dumps({"op": "auth", "session": sid})


def test_a_session_is_good_only_from_the_origin_that_logged_in(serve: Any, tmp_path: Path) -> None:
    with console(serve, token_file=_token_file(tmp_path)) as (_d, face):
        own = origin(face)
        page = login(face, **{"Sec-Fetch-Site": "same-origin"})  # (the page's own GET)
        script = login(face)  # (no Origin, no Sec-Fetch-Site: a script with the token)
        assert opens(face, auth(page), own) == "hello"
        assert opens(face, auth(page), None) == "closed 4401"  # (taken elsewhere: nothing)
        assert opens(face, auth(script), None) == "hello"
        assert opens(face, auth(script), own) == "hello"
        assert opens(face, auth("x" * 43), own) == "closed 4401"
        assert opens(face, '{"op": "config", "id": 1}', own) == "closed 4401"
        assert opens(face, auth(page), "http://127.0.0.1:1") == "refused 403"  # (the door)
        assert face.status()["sockets_refused"] == 3
        _get(face.url + "logout", {"Authorization": f"Bearer {page}"})
        assert opens(face, auth(page), own) == "closed 4401"


def test_commands_beyond_their_type_are_refused_and_the_board_stays(serve: Any) -> None:
    """(JSON 1e400 is infinity once parsed, 1e39 beyond a float32: before, each ended the
    board's session where it was packed: a reconnect per command)"""
    rt, kept = _board()  # (a float32 H-bridge "motor", a double "arm", the int8 servo, ...)
    cfg = Config(boards=[BoardSpec(serve(rt).url)], publishers=["bus", "web"],
                 publisher_options={"web": {"port": 0}})  # fmt: skip
    with Daemon(cfg) as d:
        assert d.wait_until_up(10)
        face = next(p for p in d.publishers if isinstance(p, WebPublisher))
        sent = [("motor", "1e400"), ("motor", "-1e39"), ("motor", "NaN"), ("arm", "1e400"),
                ("servo", "128"), ("servo", "2.5"), ("motor", "0.5"), ("arm", "1e300")]  # fmt: skip

        async def go() -> list[dict[str, Any]]:
            url = face.url.replace("http", "ws") + "ws"
            out = []
            async with websockets.connect(url, additional_headers={"Origin": origin(face)}) as ws:
                await ws.recv()
                for i, (name, v) in enumerate(sent):
                    topic = f"/thesis/{name}/cmd"  # (the value as JSON text: 1e400 too)
                    await ws.send(
                        f'{{"op": "command", "id": {i}, "topic": "{topic}", "value": {v}}}'
                    )
                    while (m := json.loads(await asyncio.wait_for(ws.recv(), 10)))["op"] != "reply":
                        pass
                    out.append(m)
            return out

        replies = asyncio.run(go())
        assert [r["ok"] for r in replies] == [False] * 6 + [True] * 2, replies
        assert "not finite" in replies[0]["text"] and "beyond a float" in replies[1]["text"]
        assert wait_for(lambda: kept["motor"].got[-1:] == [0.5] and kept["arm"].got[-1:] == [1e300])
        (s,) = d.status()
        assert s["state"] == "up" and s["connects"] == 1 and s["values_refused"] == 6, s
        assert face.faults.total == 0


def test_requests_without_a_token_lock_nobody_out(serve: Any, tmp_path: Path) -> None:
    """A page of another origin in the owner's browser can make the browser request /login
    (an image, a link: no header it chooses, no Origin), from the owner's own address: such a
    request is no guess and counts nothing (found attacking the fixed console: ten of them
    locked the owner out for a minute)."""
    with console(serve, token_file=_token_file(tmp_path)) as (_d, face):
        for _ in range(10):
            assert _get(face.url + "login")[0] == 401
        assert login(face)  # (the owner, from the same address: in)
        assert face.status()["logins_refused"] == 0
