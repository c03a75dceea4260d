"""The web console's one listener: the page's files and its WebSocket on one port, over TLS
where configured (websockets' asyncio server; plain HTTP GETs are answered in
``process_request``).  Its own thread and asyncio loop; the daemon's threads only touch the
model (web_model.py).

Theory of operation
-------------------
Every request passes the front door first (front_door.py: the ``Host`` the console answers to -
checked whenever TLS is off, token or not: a name rebound to 127.0.0.1 is refused -, the
``Origin`` - the page's own, or one listed - and at most ``MAX_CLIENTS`` pages).  Then:

* ``/`` and ``/static/NAME``: the page and its assets, from a table made at start (no path from
  a request ever reaches the file system), with a strict Content-Security-Policy (scripts,
  styles and connections from this origin only);
* ``/session``: whether a login is needed (JSON); ``/login``, the one place the token is taken,
  answered with a session secret the page keeps; ``/logout`` ends a session (web_auth.py: no
  cookie, since cookies do not isolate ports);
* ``/ws``: the WebSocket; where a token is set, its first message must be the session the page
  keeps, made for this socket's ``Origin`` (web_auth.py), or it is closed.

A page gets a ``hello`` (everything: model.snapshot) and then a ``tick`` every ``TICK_S`` (what
arrived, thinned; the status, polled from the daemon while pages are open).  A page that reads
too slowly has its oldest ticks dropped (counted); one whose queue still reaches ``MAX_QUEUE``
(replies to what it sends, never read) is closed (``pages_closed``).  What a page sends is one
JSON operation at a time - ``config`` (set, all or nothing; ``save``), ``reset``, ``command`` -
answered with a ``reply``; board calls run on worker threads, never on the loop.  Anything
else is dropped and counted, never logged as sent.  Commands go through the daemon's gate
(daemon/control/allowlist.py): where this face's ``commands`` is off, the gate refuses and counts
them, and the page shows no actuator controls; so does a configuration change of an actuator's keys
(daemon/session/run_config.py).
"""

from __future__ import annotations

import asyncio
import json
import logging
import ssl
import time
from collections.abc import Callable
from importlib import resources
from typing import Any

from ..errors import ConfigError, MissingLinkError
from ..logs import ErrorCounts
from ..text import safe_text
from ..topics import Command
from .front_door import FrontDoor
from .loop_server import LoopServer
from .outbox import Outbox, PeerLife
from .web_auth import AUTH_S, CLOSE_UNAUTHENTICATED, Logins
from .web_model import ConsoleModel

log = logging.getLogger(__name__)

TICK_S = 0.2
MAX_CLIENTS = 16
MAX_CLIENT_MESSAGE = 16384
BACKLOG = 50  #: ticks waiting for one page (10 s)
MAX_QUEUE = 200  #: messages waiting for one page at most (ticks and replies): more closes it
TYPES = {".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8",
         ".css": "text/css; charset=utf-8", ".png": "image/png", ".txt": "text/plain"}  # fmt: skip
CSP = (
    "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' data:; "
    "connect-src 'self'; base-uri 'none'; form-action 'self'; frame-ancestors 'none'"
)


def static_files() -> dict[str, tuple[bytes, str]]:
    """URL path -> (bytes, content type): every file the console serves, read at start."""
    files: dict[str, tuple[bytes, str]] = {}
    root = resources.files("missing_link.publishers") / "web_static"
    for item in root.iterdir():
        suffix = "." + item.name.rsplit(".", 1)[-1]
        if item.is_file() and suffix in TYPES:
            files[f"/static/{item.name}"] = (item.read_bytes(), TYPES[suffix])
    files["/"] = files["/static/index.html"]
    return files


class WebServer(LoopServer):
    def __init__(
        self,
        model: ConsoleModel,
        options: Any,
        commands_on: Callable[[], bool],
        faults: ErrorCounts,
    ) -> None:
        """``faults``: where bugs met on the console's loop are counted (the publisher's)."""
        import websockets  # noqa: F401 - (fails here, in the constructor, if it is missing)

        self.faults = faults

        self.model = model
        self.opts = options
        self.commands_on = commands_on
        self.files = static_files()
        # the Host check whenever TLS is off (with TLS the certificate names the host: a page
        # from a rebound name fails its handshake); a token does not make up for it
        self.door = FrontDoor(
            "web", options.origins, MAX_CLIENTS, same_origin=True,
            scheme="https" if options.tls else "http",
            hosts=None if options.tls else options.hosts,
        )  # fmt: skip
        self.ctx: Any = None
        self._pages: set[Outbox] = set()
        self.logins = Logins(options.token or "")
        self.pages_closed = 0  #: pages closed because they did not read their queue
        self.dropped_messages = 0
        self.dropped = 0
        self.commands_sent = 0
        self._start("web-console")

    @property
    def attached(self) -> bool:
        return self.ctx is not None

    @property
    def clients(self) -> int:
        return len(self._pages)

    def attach(self, ctx: Any) -> None:
        self.ctx = ctx

    def _ssl(self) -> ssl.SSLContext | None:
        if not self.opts.tls:
            return None
        ctx = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
        try:
            ctx.load_cert_chain(self.opts.cert, self.opts.key)
        except (OSError, ssl.SSLError) as e:
            raise ConfigError(f"[web] cert/key: cannot load {self.opts.cert}: {e}") from None
        return ctx

    # ---- the loop -----------------------------------------------------------------------------
    async def _serve(self, stop: asyncio.Future[None]) -> None:
        from websockets.asyncio.server import serve

        async with serve(
            self._handle,
            self.opts.host,
            self.opts.port,
            ssl=self._ssl(),
            process_request=self._http,
            max_size=MAX_CLIENT_MESSAGE,
            server_header=None,
            logger=_quiet_logger(),
        ) as server:
            self._listening(server)
            ticker = asyncio.ensure_future(self._tick())
            try:
                await stop
            finally:
                ticker.cancel()
                await asyncio.gather(ticker, return_exceptions=True)

    async def _tick(self) -> None:
        while True:
            await asyncio.sleep(TICK_S)
            try:
                if not self._pages:  # (still taken: an inbox nobody reads is no loss, and a
                    self.model.drain(time.time())  # page opened later shows the last 30 s)
                    continue
                if self.ctx is not None:
                    self.model.set_status(self.ctx.status(), self.ctx.publisher_status())
                msg = json.dumps(self.model.drain(time.time()), separators=(",", ":"))
            except Exception as e:  # noqa: BLE001 - a bug of ours: counted, said once; the
                self.faults.caught("tick", e)  # console goes on
                continue
            for page in list(self._pages):
                if len(page.out) >= BACKLOG:
                    page.out.popleft()
                    self.dropped += 1
                page.out.append(msg)
                page.wake.set()

    # ---- HTTP ---------------------------------------------------------------------------------
    def _http(self, connection: Any, request: Any) -> Any:
        path = request.path.split("?", 1)[0]
        if getattr(request, "method", "GET") != "GET":
            return self._respond(405, b"GET only\n", "text/plain")
        why = self.door.refusal(request, len(self._pages) if path == "/ws" else 0)
        if why is not None:
            return self._respond(why[0], why[1].encode(), "text/plain")
        if path == "/ws":
            return None  # (a session is its first message: web_auth.py)
        if path == "/session":
            body = {"token": bool(self.opts.token), "name": self.opts.name}
            return self._respond(200, json.dumps(body).encode(), "application/json")
        if path == "/login":
            status, text = self.logins.login(
                request.headers.get("Authorization", ""), _address(connection),
                self._origin_of(request), time.monotonic(),
            )  # fmt: skip
            if status == 401:
                log.warning("web: a login refused (wrong token)")  # (never what was given)
            ctype = "application/json" if status == 200 else "text/plain"
            return self._respond(status, text, ctype)
        if path == "/logout":
            self.logins.logout(request.headers.get("Authorization", ""))
            return self._respond(204, b"", "text/plain")
        found = self.files.get(path)
        if found is None:
            return self._respond(404, b"Not found\n", "text/plain")
        return self._respond(200, *found)

    def _respond(self, status: int, body: bytes, ctype: str) -> Any:
        from websockets.datastructures import Headers
        from websockets.http11 import Response

        reason = {200: "OK", 204: "No Content", 401: "Unauthorized", 403: "Forbidden",
                  404: "Not Found", 405: "Method Not Allowed", 421: "Misdirected Request",
                  429: "Too Many Requests", 503: "Service Unavailable"}.get(status, "")  # fmt: skip
        headers = Headers(
            [("Content-Type", ctype), ("Content-Length", str(len(body))),
             ("Content-Security-Policy", CSP), ("X-Content-Type-Options", "nosniff"),
             ("Referrer-Policy", "no-referrer"), ("Cache-Control", "no-store"),
             ("Connection", "close")]
        )  # fmt: skip
        return Response(status, reason, headers, body)

    # ---- a page's WebSocket -------------------------------------------------------------------
    async def _handle(self, ws: Any) -> None:
        page = Outbox(ws)
        async with PeerLife(self.faults, "page") as life:  # (what ends it ends this page only)
            if not await self._admitted(ws):
                await ws.close(CLOSE_UNAUTHENTICATED, "log in first")
                return
            if self.ctx is not None:  # (the status now: polled only while pages are open)
                self.model.set_status(self.ctx.status(), self.ctx.publisher_status())
            hello = {"op": "hello", "name": self.opts.name, "commands": self.commands_on(),
                     "attached": self.attached, "window_s": 30,
                     **self.model.snapshot()}  # fmt: skip
            page.out.append(json.dumps(hello, separators=(",", ":")))
            page.wake.set()
            life.join(page, self._pages)
            async for msg in ws:
                reply = await self._take(msg)
                if reply is None:
                    self.dropped_messages += 1
                    log.warning("web: a page's message dropped (not a console operation)")
                elif len(page.out) >= MAX_QUEUE:  # it sends and never reads: its replies
                    self.pages_closed += 1  # would grow without end
                    log.warning("web: a page closed: %d messages wait for it unread", MAX_QUEUE)
                    break
                else:
                    page.out.append(json.dumps(reply))
                    page.wake.set()

    def _origin_of(self, request: Any) -> str | None:
        """The page's origin a login comes from: its ``Origin``, or this console's own where
        the browser says the request is same-origin (a GET sends no ``Origin`` then); None
        for a script (web_auth.py)."""
        origin = request.headers.get("Origin")
        if origin is None and request.headers.get("Sec-Fetch-Site") == "same-origin":
            origin = f"{self.door.scheme}://{request.headers.get('Host', '')}"
        return None if origin is None else str(origin)

    async def _admitted(self, ws: Any) -> bool:
        """Where a token is set: the socket's first message is a session made for its Origin
        (web_auth.py), within AUTH_S."""
        if not self.opts.token:
            return True
        try:
            first = await asyncio.wait_for(ws.recv(), AUTH_S)
        except TimeoutError:
            first = None
        origin = ws.request.headers.get("Origin") if ws.request is not None else None
        if self.logins.admits(first, origin, time.monotonic()):
            return True
        log.warning("web: a page's WebSocket closed: no session of its origin")
        return False

    async def _take(self, msg: Any) -> dict[str, Any] | None:
        """A page's operation done, and its reply; None: not an operation of the console."""
        if not isinstance(msg, str):
            return None
        try:
            m = json.loads(msg)
        except (ValueError, RecursionError):
            return None
        if not isinstance(m, dict) or not isinstance(m.get("id"), int):
            return None
        op, board = m.get("op"), m.get("board")
        if op == "command":
            return {"op": "reply", "id": m["id"], **self._command(m.get("topic"), m.get("value"))}
        if op not in ("config", "reset") or not isinstance(board, str):
            return None
        values = m.get("set", {})
        if not isinstance(values, dict) or not all(isinstance(k, str) for k in values):
            return None
        if not all(isinstance(m.get(k, False), bool) for k in ("save", "erase")):
            return {
                "op": "reply",
                "id": m["id"],
                "ok": False,
                "text": "save and erase: true or false",
            }
        if op == "config" and not values and not m.get("save"):
            return {"op": "reply", "id": m["id"], "ok": True, "text": "nothing to set"}
        if self.ctx is None:
            return {"op": "reply", "id": m["id"], "ok": False,
                    "text": "this console is not attached to a daemon: read-only"}  # fmt: skip
        ctx, on = self.ctx, self.commands_on()  # (an actuator's keys are commands: the gate's)
        if op == "reset":
            erase = bool(m.get("erase"))
            call: Callable[[], Any] = lambda: ctx.reset_config(board, erase, by="web", commands=on)  # noqa: E731
        else:
            save = bool(m.get("save"))
            call = lambda: ctx.configure(board, values, save, by="web", commands=on)  # noqa: E731
        try:
            result = await asyncio.to_thread(call)
        except (ConfigError, MissingLinkError) as e:
            return {"op": "reply", "id": m["id"], "ok": False, "text": safe_text(str(e), 300)}
        return {"op": "reply", "id": m["id"], "ok": True, "values": result}

    def _command(self, topic: Any, value: Any) -> dict[str, Any]:
        deliver = self.model.deliver(topic) if isinstance(topic, str) else None
        if deliver is None:
            return {"ok": False, "text": "no such command topic"}
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            return {"ok": False, "text": "a command is one number"}
        try:
            deliver(Command([value]))  # (the daemon's gate: refused and counted where off)
        except ValueError as e:
            return {"ok": False, "text": safe_text(str(e), 300)}
        if not self.commands_on():
            return {"ok": False, "text": "commands are off on this console ([web] commands)"}
        self.commands_sent += 1
        return {"ok": True, "text": "sent"}


def _quiet_logger() -> logging.Logger:
    """websockets' logger for the console: never DEBUG, whatever the root's level, since its
    DEBUG lines may carry handshake headers (a session cookie)."""
    logger = logging.getLogger(__name__ + ".websockets")
    logger.setLevel(logging.INFO)
    return logger


def _address(connection: Any) -> str:
    """The client's address (without its port): what failed logins are counted by."""
    try:
        return str(connection.remote_address[0])
    except (AttributeError, IndexError, TypeError):  # (no address: one shared entry)
        return "?"
