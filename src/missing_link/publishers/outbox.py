"""What a WebSocket server sends one peer (the web console's page, a Foxglove client): its
queues and the coroutine that writes them, written once for both servers."""

from __future__ import annotations

import asyncio
from collections import deque
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
