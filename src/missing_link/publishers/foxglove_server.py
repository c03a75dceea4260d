"""The Foxglove live view's only listener (docs/security.md): the Foxglove WebSocket protocol
served by missing-link itself, behind a front door that checks who may look and what they may
say.

Why not the Foxglove SDK's server: it opens a port of its own (foxglove-sdk 0.30's
``start_server`` binds a TCP host and port, with no unix socket, no client authentication and no
hook on a connection), and whoever reaches that port - any local user, any web page in a browser
on the robot computer - gets every channel, whatever a gate in front of it checks.  So the view
speaks the protocol's subset it needs itself (``foxglove.websocket.v1``, under the SDK's
``foxglove.sdk.v1`` name too): ``serverInfo`` and ``advertise`` on connection, ``advertise`` of
new channels, ``subscribe``/``unsubscribe``, binary message data (opcode 1: subscription id,
log time ns, payload); no client publishing, parameters, services or assets.

The front door (front_door.py, shared with the web console): a browser says where a page came from
in ``Origin``; a client with an ``Origin`` not in ``origins`` is refused (HTTP 403) and counted
(``refused_origins``); native clients send none and are admitted.  At most ``MAX_CLIENTS`` at
once (more: 503, counted).  What an admitted client sends is taken only when it is a subscribe
or unsubscribe that checks (or another read-only operation, ignored); anything else is dropped
and counted (``dropped_messages``), never logged as sent.  Every refusal is logged through
``logs.SafeLog`` (cleaned, rate-limited).

Threads: ``add_channel`` and ``log`` are called from any thread (a board's reader) and never
block: messages wait in a bounded inbox that the view's own asyncio loop fans out to the
subscribers, each with a bounded backlog (the oldest data dropped and counted in ``dropped``
when a client reads too slowly; channel advertisements are never dropped).
"""

from __future__ import annotations

import asyncio
import json
import logging
import struct
import threading
import time
from collections import deque
from collections.abc import Sequence
from typing import Any

from ..delegate import Delegate
from ..logs import ErrorCounts
from .front_door import FrontDoor
from .loop_server import LoopServer
from .outbox import Outbox, PeerLife

log = logging.getLogger(__name__)

SUBPROTOCOLS = ("foxglove.sdk.v1", "foxglove.websocket.v1")
#: read-only client operations of the protocol whose capabilities the view does not offer:
#: taken and ignored (a client may probe), not counted as dropped
IGNORED_OPS = frozenset(
    {"getParameters", "subscribeParameterUpdates", "unsubscribeParameterUpdates",
     "subscribeConnectionGraph", "unsubscribeConnectionGraph", "fetchAsset"}
)  # fmt: skip
MAX_CLIENT_MESSAGE = 65536
MAX_CLIENTS = 32
MAX_SUBSCRIPTIONS = 4096  #: per client
BACKLOG = 1024  #: data messages waiting for one client
INBOX = 8192  #: data messages waiting for the loop
_U32 = 0xFFFFFFFF


class _Client(Outbox):
    """A client: its control messages (``urgent``) go before its data messages (``out``)."""

    def __init__(self, ws: Any) -> None:
        Outbox.__init__(self, ws)
        self.subs: dict[int, int] = {}  # subscription id -> channel id
        self.by_channel: dict[int, int] = {}  # channel id -> subscription id


class LiveView(LoopServer):
    loop_kind = "view loop"

    def __init__(
        self,
        host: str,
        port: int,
        origins: Sequence[str],
        name: str = "missing-link",
        faults: ErrorCounts | None = None,
    ) -> None:
        """``faults``: where bugs met on the view's loop are counted (the publisher's)."""
        import websockets  # noqa: F401 - (imported here: a view that is not asked costs nothing)

        self.faults = faults if faults is not None else ErrorCounts(log, "foxglove view")

        self.door = FrontDoor("foxglove", origins, MAX_CLIENTS)
        self.name = name
        self.dropped_messages = 0
        self.dropped = 0
        self._channels: dict[int, dict[str, Any]] = {}
        self._clients: set[_Client] = set()
        self._inbox: deque[tuple[int, bytes, int]] = deque()
        self._lock = threading.Lock()
        self._scheduled = False
        self._session = str(time.time_ns())
        self._host, self._port = host, port
        self._start("foxglove-view")

    refused_origins = Delegate[int]("door")
    refused_clients = Delegate[int]("door")

    @property
    def clients(self) -> int:
        return len(self._clients)

    @property
    def subscriptions(self) -> int:
        return sum(len(c.subs) for c in list(self._clients))

    # ---- any thread ---------------------------------------------------------------------------
    def add_channel(self, topic: str, schema_name: str, schema: str) -> int:
        """A channel (ros2msg schema, CDR messages); advertised to every client.  Its id."""
        with self._lock:
            cid = len(self._channels) + 1
            ch = {"id": cid, "topic": topic, "encoding": "cdr", "schemaName": schema_name,
                  "schema": schema, "schemaEncoding": "ros2msg"}  # fmt: skip
            self._channels[cid] = ch
        self._call(self._advertise, [ch])
        return cid

    def log(self, channel: int, data: bytes, log_time_ns: int) -> None:
        """One message on ``channel`` to its subscribers (never blocks)."""
        if not self._clients:
            return
        with self._lock:
            if len(self._inbox) >= INBOX:
                self._inbox.popleft()
                self.dropped += 1
            self._inbox.append((channel, data, min(max(0, log_time_ns), 2**64 - 1)))
            if self._scheduled:
                return
            self._scheduled = True
        self._call(self._fan_out)

    # ---- the loop -----------------------------------------------------------------------------
    async def _serve(self, stop: asyncio.Future[None]) -> None:
        from websockets.asyncio.server import serve

        async with serve(
            self._handle,
            self._host,
            self._port,
            subprotocols=list(SUBPROTOCOLS),  # type: ignore[arg-type]
            process_request=self._check,
            max_size=MAX_CLIENT_MESSAGE,
            logger=logging.getLogger(__name__ + ".websockets"),
        ) as server:
            self._listening(server)
            await stop

    def _check(self, connection: Any, request: Any) -> Any:
        return self.door.check(connection, request, len(self._clients))

    async def _handle(self, ws: Any) -> None:
        client = _Client(ws)
        info = {"op": "serverInfo", "name": self.name, "capabilities": [],
                "metadata": {}, "sessionId": self._session}  # fmt: skip
        client.urgent.append(json.dumps(info))
        with self._lock:
            channels = list(self._channels.values())
        client.urgent.append(json.dumps({"op": "advertise", "channels": channels}))
        client.wake.set()
        async with PeerLife(self.faults, "client") as life:  # (what ends it ends this client only)
            life.join(client, self._clients)
            async for msg in ws:
                if not self._take(client, msg):
                    self.dropped_messages += 1
                    log.warning("foxglove: a client message dropped (not a view operation)")

    def _advertise(self, channels: list[dict[str, Any]]) -> None:
        msg = json.dumps({"op": "advertise", "channels": channels})
        for client in self._clients:
            client.urgent.append(msg)
            client.wake.set()

    def _fan_out(self) -> None:
        with self._lock:
            items = list(self._inbox)
            self._inbox.clear()
            self._scheduled = False
        head = struct.Struct("<BIQ")
        for channel, data, stamp in items:
            for client in self._clients:
                sub = client.by_channel.get(channel)
                if sub is None:
                    continue
                if len(client.out) >= BACKLOG:
                    client.out.popleft()
                    self.dropped += 1
                client.out.append(head.pack(1, sub, stamp) + data)
                client.wake.set()

    # ---- what a client says -------------------------------------------------------------------
    def _take(self, client: _Client, msg: Any) -> bool:
        """Whether ``msg`` is an operation of the view (then done)."""
        if not isinstance(msg, str):
            return False  # binary client messages are client publishes: the view takes none
        try:
            m = json.loads(msg)
        except (ValueError, RecursionError):
            return False
        op = m.get("op") if isinstance(m, dict) else None
        if op == "subscribe":
            return self._subscribe(client, m.get("subscriptions"))
        if op == "unsubscribe":
            ids = m.get("subscriptionIds")
            if not isinstance(ids, list) or not all(_u32(i) for i in ids):
                return False
            for i in ids:
                cid = client.subs.pop(i, None)
                if cid is not None:
                    client.by_channel.pop(cid, None)
            return True
        return isinstance(op, str) and op in IGNORED_OPS  # (an op of {} is no op, no bug)

    def _subscribe(self, client: _Client, subs: Any) -> bool:
        if not isinstance(subs, list) or len(client.subs) + len(subs) > MAX_SUBSCRIPTIONS:
            return False
        pairs: list[tuple[int, int]] = [
            (s["id"], s["channelId"])
            for s in subs
            if isinstance(s, dict) and _u32(s.get("id")) and _u32(s.get("channelId"))
        ]
        if len(pairs) != len(subs):
            return False
        for sub, cid in pairs:
            # (a channel that does not exist, a subscription id in use, a channel subscribed
            # already: ignored, as the protocol allows)
            if cid in self._channels and sub not in client.subs and cid not in client.by_channel:
                client.subs[sub] = cid
                client.by_channel[cid] = sub
        return True


def _u32(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and 0 <= v <= _U32
