"""The web console (publishers/web*.py) without a browser: what it serves, who it lets in, what a
page may do through its WebSocket, and that the bundled uPlot is node_modules' own
(tests/test_web_browser.py drives the page in Chromium)."""

from __future__ import annotations

import asyncio
import json
import logging
import os
import re
import ssl
import subprocess
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
import websockets

from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config, parse_config
from missing_link.errors import ConfigError
from missing_link.publishers.web import WebPublisher, parse_addr, parse_options
from missing_link.publishers.web_model import thin
from missing_link.virtual.sims import rangers

from .helpers import ML, wait_for

ROOT = Path(__file__).resolve().parent.parent
STATIC = ROOT / "src" / "missing_link" / "publishers" / "web_static"
UPLOT = ROOT / "node_modules" / "uplot"
TOKEN = "a-token-of-thirty-two-characters"


# ---- the bundled front end -------------------------------------------------------------------
def test_bundled_uplot_is_node_modules_copy() -> None:
    """design.md: generated code is plain, marked, and checked against its source."""
    assert UPLOT.is_dir(), "node_modules/uplot is missing: run make node"
    pairs = {"uPlot.iife.min.js": "dist/uPlot.iife.min.js", "uPlot.min.css": "dist/uPlot.min.css",
             "uPlot.LICENSE.txt": "LICENSE"}  # fmt: skip
    for ours, theirs in pairs.items():
        assert (STATIC / ours).read_bytes() == (UPLOT / theirs).read_bytes(), (
            f"{ours} differs from node_modules/uplot/{theirs}: run scripts/build-web.sh"
        )
    pinned = json.loads((ROOT / "package.json").read_text())["dependencies"]["uplot"]
    assert json.loads((UPLOT / "package.json").read_text())["version"] == pinned
    assert "linguist-generated" in (ROOT / ".gitattributes").read_text()


def test_the_page_loads_nothing_from_elsewhere() -> None:
    for f in STATIC.iterdir():
        if f.suffix in (".html", ".js", ".css") and not f.name.startswith("uPlot"):
            text = f.read_text()
            assert not re.search(r"(src|href)=\"(https?:)?//", text), f.name
            assert "innerHTML" not in text, f"{f.name}: board text is set as text only"


# ---- options ---------------------------------------------------------------------------------
def test_options_refuse_a_network_address_without_tls_and_token(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="needs TLS"):
        parse_options({"host": "0.0.0.0"})
    tok = tmp_path / "token"
    tok.write_text(TOKEN)
    tok.chmod(0o644)
    with pytest.raises(ConfigError, match="chmod 600"):
        parse_options({"token_file": str(tok)})
    tok.chmod(0o600)
    with pytest.raises(ConfigError, match="needs TLS"):
        parse_options({"host": "192.0.2.1", "token_file": str(tok)})
    o = parse_options({"host": "0.0.0.0", "token_file": str(tok), "cert": "c", "key": "k"})
    assert o.token == TOKEN and o.tls and o.commands is False  # (off the loopback: opt in)
    assert TOKEN not in repr(o)
    assert parse_options({}).commands is True  # loopback: on, as every face
    assert parse_options({"commands": False}).commands is False
    with pytest.raises(ConfigError, match="commands"):
        parse_options({"commands": "yes"})
    with pytest.raises(ConfigError, match="comands: unknown key"):
        parse_options({"comands": False})
    short = tmp_path / "short"
    short.write_text("abc")
    short.chmod(0o600)
    with pytest.raises(ConfigError, match="at least"):
        parse_options({"token_file": str(short)})


def test_addresses_and_the_web_table() -> None:
    assert parse_addr("127.0.0.1:9000") == ("127.0.0.1", 9000)
    assert parse_addr("[::1]:9000") == ("::1", 9000)
    assert parse_addr("9000") == ("127.0.0.1", 9000)
    with pytest.raises(ConfigError, match="ADDR:PORT"):
        parse_addr("host:port")
    cfg = parse_config({"daemon": {"publishers": ["bus", "web"]}, "web": {"commands": False}})
    assert cfg.publisher_options["web"] == {"commands": False}


def test_thin_keeps_the_first_and_the_newest() -> None:
    points = [[i] for i in range(1000)]
    out = thin(points, 50)
    assert len(out) == 50 and out[0] == [0] and out[-1] == [999]
    assert thin(points[:10], 50) == points[:10]


# ---- a daemon with the console ---------------------------------------------------------------
@contextmanager
def console(
    serve: Any, store: str | None = None, **web: Any
) -> Iterator[tuple[Daemon, WebPublisher]]:
    """The demo's two boards (board_b saving its configuration to ``store``) and a daemon with
    the console on a free loopback port, attached."""
    a = serve("encoder_servo", "tcp://127.0.0.1:0")
    b = serve(rangers(config_file=store), "tcp://127.0.0.1:0")
    cfg = Config(
        boards=[BoardSpec(a.url, name="board_a"), BoardSpec(b.url, name="board_b")],
        publishers=["bus", "web"],
        publisher_options={"web": {"port": 0, **web}},
    )
    with Daemon(cfg) as d:
        face = next(p for p in d.publishers if isinstance(p, WebPublisher))
        assert face.server.attached  # (the daemon started it with its verbs: no CLI needed)
        assert d.wait_until_up(10)
        yield d, face


def origin(face: WebPublisher) -> str:
    return face.url.rstrip("/")


async def _session(face: WebPublisher, ops: list[dict[str, Any]], **kw: Any) -> list[Any]:
    """Open the WebSocket as the page would, wait for a tick with data, send ``ops``; the
    hello, that tick and the replies."""
    url = face.url.replace("http", "ws") + "ws"
    headers = {"Origin": origin(face), **kw.get("headers", {})}
    async with websockets.connect(url, additional_headers=headers, ssl=kw.get("ssl")) as ws:
        if "session" in kw:  # (a console with a token: its first message, web_auth.py)
            await ws.send(json.dumps({"op": "auth", "session": kw["session"]}))
        hello = json.loads(await asyncio.wait_for(ws.recv(), 10))
        while True:
            tick = json.loads(await asyncio.wait_for(ws.recv(), 10))
            if tick["op"] == "tick" and len(tick["data"]) >= 2:
                break
        replies = []
        for op in ops:
            await ws.send(json.dumps(op))
            while (m := json.loads(await asyncio.wait_for(ws.recv(), 10)))["op"] != "reply":
                pass
            replies.append(m)
        return [hello, tick, *replies]


def _get(url: str, headers: dict[str, str] | None = None, **kw: Any) -> tuple[int, Any, bytes]:
    req = urllib.request.Request(url, headers=headers or {})
    try:
        with urllib.request.urlopen(req, timeout=10, **kw) as r:
            return r.status, r.headers, r.read()
    except urllib.error.HTTPError as e:
        return e.code, e.headers, e.read()


def test_page_and_assets_served_with_a_strict_policy(serve: Any) -> None:
    with console(serve) as (_d, face):
        status, headers, body = _get(face.url)
        assert status == 200 and b"/static/console.js" in body
        assert "script-src 'self'" in headers["Content-Security-Policy"]
        assert headers["X-Content-Type-Options"] == "nosniff"
        status, headers, body = _get(face.url + "static/uPlot.iife.min.js")
        assert status == 200 and headers["Content-Type"].startswith("text/javascript")
        assert body == (STATIC / "uPlot.iife.min.js").read_bytes()
        for path in ("static/../web.py", "static/%2e%2e/web.py", "static/nothing.js", "etc"):
            assert _get(face.url + path)[0] == 404, path


def test_a_page_sees_every_board_its_status_and_values(serve: Any) -> None:
    with console(serve) as (_d, face):
        hello, tick, _ = asyncio.run(_session(face, [{"op": "config", "id": 1, "board": "nope",
                                                       "set": {"x.y": 1}}]))  # fmt: skip
    assert hello["commands"] is True and hello["attached"] is True
    topics = {t["topic"]: t for t in hello["topics"]}
    assert {"/board_a/quad", "/board_a/servo", "/board_b/dist_ir", "/board_b/dist_us"} <= set(
        topics
    )  # (and not the standard types' mirrors, /board_b/dist_ir/range: shown once)
    assert "/board_b/dist_ir/range" not in topics
    ir = topics["/board_b/dist_ir"]
    assert ir["unit"] == "mm" and ir["channels"] == 8
    assert topics["/board_a/servo"]["command"] == "/board_a/servo/cmd"
    keys = {k["key"]: k for k in hello["config"]["board_b"]["keys"]}
    assert keys["dist_ir.rate_hz"]["unit"] == "Hz" and keys["dist_ir.rate_hz"]["kind"] == "float"
    assert keys["dist_ir.rate_hz"]["saved"] is None  # nothing saved: the board boots defaults
    boards = {b["board"]: b for b in tick["boards"]}
    assert boards["board_a"]["state"] == "up" and "rtt_us" in boards["board_a"]
    t, *values = tick["data"]["/board_b/dist_ir"][-1]
    assert abs(t - time.time()) < 5 and len(values) == 8
    assert tick["rates"]["/board_a/quad"]["count"] > 0


def test_configuration_all_or_nothing_save_and_reset(serve: Any, tmp_path: Path) -> None:
    ops = [
        {"op": "config", "id": 1, "board": "board_b", "set": {"dist_ir.rate_hz": "7"}},
        {"op": "config", "id": 2, "board": "board_b",
         "set": {"dist_us.rate_hz": "9", "dist_ir.rate_hz": "9999"}},
        {"op": "config", "id": 3, "board": "board_b", "set": {}, "save": True},
        {"op": "reset", "id": 4, "board": "board_b"},
    ]  # fmt: skip
    erase = [{"op": "reset", "id": 5, "board": "board_b", "erase": True}]
    with console(serve, store=str(tmp_path / "flash")) as (d, _face):
        before = d.board_config("board_b")["dist_us.rate_hz"]
        _h, _t, one, two, three, four = asyncio.run(_session(_face, ops))
        assert one["ok"] and one["values"]["dist_ir.rate_hz"] == 7
        assert not two["ok"] and "dist_ir.rate_hz" in two["text"] and "0.1..26" in two["text"]
        assert d.board_config("board_b")["dist_us.rate_hz"] == before  # none of them
        assert three["ok"] and three["values"]["dist_ir.rate_hz"] == 7
        assert four["ok"] and four["values"]["dist_ir.rate_hz"] == 25
        view = _face.model.snapshot()["config"]["board_b"]
        _h, _t, five = asyncio.run(_session(_face, erase))
        erased = _face.model.snapshot()["config"]["board_b"]
    assert five["ok"] and erased["state"] == ["defaults"]  # (nothing saved)
    assert {k["key"]: k["saved"] for k in erased["keys"]}["dist_ir.rate_hz"] is None
    key = {k["key"]: k for k in view["keys"]}["dist_ir.rate_hz"]
    # the board says a saved configuration differs from what runs; which values it holds the
    # console knows because it saw the running values when nothing differed (after the save)
    assert view["state"] == ["changed", "saved"] and key["value"] == 25 and key["saved"] == 7


def test_a_forged_command_is_refused_where_commands_are_off(serve: Any) -> None:
    forged = {"op": "command", "id": 1, "topic": "/board_a/servo/cmd", "value": 40}
    with console(serve, commands=False) as (d, face):
        hello, _t, reply = asyncio.run(_session(face, [forged]))
        time.sleep(0.3)
        board_a = {s["board"]: s for s in d.status()}["board_a"]
        refused = {p["publisher"]: p for p in d.publisher_status()}["web"]["commands_refused"]
    assert hello["commands"] is False
    assert not reply["ok"] and "off" in reply["text"]
    assert board_a["commands"] == 0 and refused == 1  # never reached the board; counted


def test_a_command_reaches_the_board_where_commands_are_on(serve: Any) -> None:
    cmd = {"op": "command", "id": 1, "topic": "/board_a/servo/cmd", "value": 40}
    with console(serve) as (d, face):
        _h, _t, reply = asyncio.run(_session(face, [cmd]))
        board_a = lambda: {s["board"]: s for s in d.status()}["board_a"]  # noqa: E731
        assert wait_for(lambda: board_a()["commands"] != 0, 5), "the command never reached it"
    assert reply["ok"]


# ---- the front door --------------------------------------------------------------------------
def test_other_sites_pages_and_rebound_names_are_refused(serve: Any, caplog: Any) -> None:
    async def try_ws(face: WebPublisher, headers: dict[str, str], name: str = "") -> int:
        url = face.url.replace("http", "ws") + "ws"
        where = {}
        if name:  # (a name that resolves to 127.0.0.1: the request says that name)
            where = {"host": "127.0.0.1", "port": int(port)}
            url = f"ws://{name}:{port}/ws"
        try:
            async with websockets.connect(url, additional_headers=headers, **where) as ws:
                await ws.recv()
                return 101
        except websockets.InvalidStatus as e:
            return int(e.response.status_code)

    with console(serve) as (_d, face):
        port = face.url.rsplit(":", 1)[1].strip("/")
        assert asyncio.run(try_ws(face, {"Origin": "http://evil.example"})) == 403
        rebound = {"Origin": f"http://evil.example:{port}"}  # (DNS rebinding)
        assert asyncio.run(try_ws(face, rebound, "evil.example")) == 421
        two = {"Origin": origin(face), "Host": f"evil.example:{port}"}  # (and the client's own)
        assert asyncio.run(try_ws(face, two)) == 400
        assert _get(face.url, {"Host": f"evil.example:{port}"})[0] == 421
        assert asyncio.run(try_ws(face, {"Origin": origin(face)})) == 101
        assert asyncio.run(try_ws(face, {})) == 101  # a native client (no Origin)
        st = face.status()
    assert st["origins_refused"] == 1 and st["hosts_refused"] == 3
    assert any("evil.example" in r.getMessage() for r in caplog.records)


def _certs(tmp: Path) -> Path:
    script = ROOT / "examples" / "security" / "make-certs.sh"
    subprocess.run(["sh", str(script), str(tmp)], check=True, capture_output=True, timeout=60)
    return tmp


@pytest.mark.slow
def test_tls_and_a_token_session(serve: Any, tmp_path: Path, caplog: Any) -> None:
    certs = _certs(tmp_path / "certs")
    tok = tmp_path / "token"
    tok.write_text(TOKEN + "\n")
    tok.chmod(0o600)
    caplog.set_level(logging.DEBUG)
    opts = {"cert": str(certs / "daemon.pem"), "key": str(certs / "daemon.key"),
            "token_file": str(tok)}  # fmt: skip
    tls = ssl.create_default_context(cafile=str(certs / "ca.pem"))
    with console(serve, **opts) as (_d, face):
        assert face.url.startswith("https://127.0.0.1:")
        assert _get(face.url, context=tls)[0] == 200  # (the page itself holds nothing)
        status, _h, body = _get(face.url + "session", context=tls)
        assert json.loads(body) == {"token": True, "name": "missing-link"}
        with pytest.raises(websockets.ConnectionClosed) as closed:  # (no session: closed)
            asyncio.run(_session(face, [], ssl=tls))
        assert closed.value.rcvd is not None and closed.value.rcvd.code == 4401
        assert _get(face.url + "login", {"Authorization": "Bearer wrong"}, context=tls)[0] == 401
        status, headers, body = _get(face.url + "login", {"Authorization": f"Bearer {TOKEN}",
                                     "Origin": origin(face)}, context=tls)  # fmt: skip
        assert status == 200 and "Set-Cookie" not in headers  # (cookies go to every port)
        sid = json.loads(body)["session"]
        assert TOKEN not in sid
        hello, *_ = asyncio.run(_session(face, [], ssl=tls, session=sid))
        assert hello["op"] == "hello"
        for _ in range(5):  # a guesser is stopped after five wrong tokens a minute
            _get(face.url + "login", {"Authorization": "Bearer guess"}, context=tls)
        right = {"Authorization": f"Bearer {TOKEN}"}
        assert _get(face.url + "login", right, context=tls)[0] == 429
        assert face.status()["logins_refused"] >= 6
    server_side = [r.getMessage() for r in caplog.records if r.name != "websockets.client"]
    assert server_side and not [m for m in server_side if TOKEN in m or sid in m]


@pytest.mark.slow
def test_demo_serves_the_console(tmp_path: Path) -> None:
    proc = subprocess.Popen(
        [*ML, "demo", "--duration", "8", "--web", "127.0.0.1:0",
         "--record", str(tmp_path / "rec")],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path,
        env={**os.environ, "COLUMNS": "100"},
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        url = ""
        for line in proc.stdout:
            m = re.search(r"device console in a browser: (\S+)", line)
            if m:
                url = m.group(1)
                break
        assert url, proc.stderr.read() if proc.stderr else ""

        async def boards() -> set[str]:
            headers = {"Origin": url.rstrip("/")}
            ws_url = url.replace("http", "ws") + "ws"
            async with websockets.connect(ws_url, additional_headers=headers) as ws:
                while True:
                    m = json.loads(await asyncio.wait_for(ws.recv(), 10))
                    up = {b["board"] for b in m.get("boards", []) if b["state"] == "up"}
                    if len(up) == 2:
                        return up

        assert asyncio.run(boards()) == {"board_a", "board_b"}
        out, _err = proc.communicate(timeout=60)
        assert proc.returncode == 0, out
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_samples_with_no_page_open_are_kept_not_counted_dropped() -> None:
    """The demo said "web 20616 dropped" with no page open: the ticks took nothing then, so
    each topic's inbox filled and every sample after it was counted a drop."""
    from missing_link.descriptors import parse_transds
    from missing_link.publishers.web_model import INBOX
    from missing_link.topics import Topic, Update

    (t,) = parse_transds("transds/1\nx,0,p,M,1,int32_t,-1\n")
    topic = Topic.for_transducer("/b/x", "x", t, "missing_link_msgs")
    face = WebPublisher({"port": 0})
    try:
        face.add_topic(topic)
        now = time.time_ns()
        for i in range(3 * INBOX):
            face.publish(Update.build(topic=topic, board_us=[i], host_ns=[now + i * 1000],
                                      values=[i], seq=i, lost=0, recv_ns=i))  # fmt: skip
            if i % (INBOX // 2) == 0:  # (a tick between: the inbox is emptied, page or not)
                assert wait_for(lambda: face.model.waiting() == 0, 10)
        assert wait_for(lambda: face.model.waiting() == 0, 10)
        assert face.model.dropped() == 0
        assert face.model.snapshot()["history"]["/b/x"]  # (what a page opened now is shown)
    finally:
        face.close()
