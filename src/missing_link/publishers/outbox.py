"""What a WebSocket server sends one peer (the web console's page, a Foxglove client): its
queues and the coroutine that writes them, and the peer's life on the server (PeerLife), written
once for both servers."""

from __future__ import annotations

import asyncio
from collections import deque
from types import TracebackType
from typing import Any

from ..logs import ErrorCounts


class Outbox:
    """One peer's queues on the server's loop: ``urgent`` (sent before anything waiting in
    ``out``: a Foxglove client's server info and advertisements) and ``out``; whoever queues a
    message sets ``wake``."""

    def __init__(self, ws: Any) -> None:
        self.ws = ws
        self.urgent: deque[str] = deque()
        self.out: deque[str | bytes] = deque()
        self.wake = asyncio.Event()

    async def write(self, faults: ErrorCounts, what: str) -> None:
        """Send what is queued, as it comes, until the connection ends (then close it: the
        reader sees the end too); a bug is counted in ``faults`` as ``what`` and ends the peer."""
        from websockets.exceptions import ConnectionClosed

        try:
            while True:
                await self.wake.wait()
                self.wake.clear()
                while self.urgent or self.out:
                    await self.ws.send((self.urgent or self.out).popleft())
        except (ConnectionClosed, OSError):
            await self.ws.close()
        except Exception as e:  # noqa: BLE001 - a bug: counted, said once; that peer ends
            faults.caught(what, e)
            await self.ws.close()


class PeerLife:
    """One peer's connection, served in ``async with PeerLife(faults, what) as life:``: a broken
    connection ends that peer only, and so does a bug serving it (counted in ``faults`` as
    ``what``, said once); ``life.join(peer, peers)`` puts it among ``peers`` and starts its
    writer, and at the end it leaves them and its writer is stopped."""

    def __init__(self, faults: ErrorCounts, what: str) -> None:
        self.faults = faults
        self.what = what
        self._peer: Outbox | None = None
        self._peers: set[Any] = set()
        self._writer: asyncio.Future[None] | None = None

    def join(self, peer: Outbox, peers: set[Any]) -> None:
        self._peer, self._peers = peer, peers
        peers.add(peer)
        self._writer = asyncio.ensure_future(peer.write(self.faults, f"{self.what} writer"))

    async def __aenter__(self) -> PeerLife:
        return self

    async def __aexit__(
        self, kind: type[BaseException] | None, e: BaseException | None, tb: TracebackType | None
    ) -> bool:
        from websockets.exceptions import ConnectionClosed

        self._peers.discard(self._peer)
        if self._writer is not None:
            self._writer.cancel()
            await asyncio.gather(self._writer, return_exceptions=True)
        if isinstance(e, (ConnectionClosed, OSError)):
            return True  # (its broken connection ends that peer only)
        if isinstance(e, Exception):  # a bug serving it ends that peer only: counted, said once
            self.faults.caught(self.what, e)
            return True
        return False
