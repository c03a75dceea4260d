"""The Foxglove live view's front door (docs/security.md): a WebSocket server in front of the
Foxglove SDK's that checks who may look and what they may say.

A web page open in a browser on the robot computer can reach ``ws://127.0.0.1:8765`` as well
as a Foxglove app can; a browser says where the page came from in the ``Origin`` header, a
native client (the Foxglove desktop app, a script) sends none.  So: a client with an ``Origin``
is refused (HTTP 403) unless that origin is in ``origins`` (``[foxglove] origins =
["https://app.foxglove.dev"]`` to use the web app), and counted.  What an admitted client sends
is handed on only if it is one of the live view's operations (subscribe, unsubscribe and the
other read-only ones; the view takes no client publishes) as well-formed JSON: anything else is
dropped and counted, so a client cannot make the SDK log text of its choosing.  Every refusal
is logged (through ``logs.SafeLog``: cleaned, rate-limited).

The SDK's own server listens on an ephemeral port on 127.0.0.1; this one on the configured
host and port.  It relays frames both ways on an asyncio loop of its own.
"""

from __future__ import annotations

import asyncio
import json
import logging
import threading
from collections.abc import Sequence
from typing import Any

from ..text import safe_text

log = logging.getLogger(__name__)

SUBPROTOCOLS = ("foxglove.sdk.v1", "foxglove.websocket.v1")
#: the client operations of the Foxglove WebSocket protocol the live view answers
CLIENT_OPS = frozenset(
    {"subscribe", "unsubscribe", "getParameters", "subscribeParameterUpdates",
     "unsubscribeParameterUpdates", "subscribeConnectionGraph", "unsubscribeConnectionGraph",
     "fetchAsset"}
)  # fmt: skip
MAX_CLIENT_MESSAGE = 65536


class OriginGate:
    def __init__(self, host: str, port: int, backend_port: int, origins: Sequence[str]) -> None:
        import websockets  # noqa: F401 - (imported here: a view that is not asked costs nothing)

        self.origins = frozenset(origins)
        self.backend = f"ws://127.0.0.1:{backend_port}"
        self.refused_origins = 0
        self.dropped_messages = 0
        self._loop = asyncio.new_event_loop()
        self._ready = threading.Event()
        self._stop: asyncio.Future[None] | None = None
        self._error: BaseException | None = None
        self.port = 0
        self._thread = threading.Thread(
            target=self._run, args=(host, port), name="foxglove-gate", daemon=True
        )
        self._thread.start()
        self._ready.wait(10)
        if self._error is not None:
            raise self._error

    def _run(self, host: str, port: int) -> None:
        asyncio.set_event_loop(self._loop)
        try:
            self._loop.run_until_complete(self._serve(host, port))
        except BaseException as e:  # noqa: BLE001 - said to the constructor
            self._error = e
            self._ready.set()

    async def _serve(self, host: str, port: int) -> None:
        from websockets.asyncio.server import serve

        self._stop = self._loop.create_future()
        async with serve(
            self._handle,
            host,
            port,
            subprotocols=list(SUBPROTOCOLS),  # type: ignore[arg-type]
            process_request=self._check,
            max_size=MAX_CLIENT_MESSAGE,
        ) as server:
            self.port = int(next(iter(server.sockets)).getsockname()[1])
            self._ready.set()
            await self._stop

    def _check(self, connection: Any, request: Any) -> Any:
        origin = request.headers.get("Origin")
        if origin is None or origin in self.origins:
            return None
        self.refused_origins += 1
        log.warning(
            "foxglove: a client from %s refused: its Origin is not in [foxglove] origins",
            safe_text(origin, 100),
        )
        return connection.respond(403, "Origin not allowed\n")

    async def _handle(self, client: Any) -> None:
        from websockets.asyncio.client import connect

        proto = client.subprotocol or SUBPROTOCOLS[0]
        sub: Any = proto  # (websockets' Subprotocol is a str)
        async with connect(self.backend, subprotocols=[sub], max_size=None) as server:

            async def down() -> None:
                async for msg in server:
                    await client.send(msg)

            async def up() -> None:
                async for msg in client:
                    if self._allowed(msg):
                        await server.send(msg)
                    else:
                        self.dropped_messages += 1
                        log.warning("foxglove: a client message dropped (not a view operation)")

            tasks = [asyncio.ensure_future(down()), asyncio.ensure_future(up())]
            _done, pending = await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
            for t in pending:
                t.cancel()

    @staticmethod
    def _allowed(msg: Any) -> bool:
        if not isinstance(msg, str):
            return False  # binary client messages are client publishes: the view takes none
        try:
            m = json.loads(msg)
        except ValueError:
            return False
        return isinstance(m, dict) and m.get("op") in CLIENT_OPS

    def close(self) -> None:
        stop = self._stop
        if stop is not None and not stop.done():
            self._loop.call_soon_threadsafe(stop.set_result, None)
        self._thread.join(5)
