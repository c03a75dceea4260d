"""The asyncio face of :class:`~missing_link.host.board.Board`: the same engine, awaited
instead of waited on (``asyncio.wrap_future`` over the link's futures)."""

from __future__ import annotations

import asyncio
import threading
from collections import deque

from ..delegate import Delegate
from ..descriptors import Transducer
from ..j2a import SifReceived
from .board import Board
from .link import DEFAULT_TIMEOUT, CallResult, ProgressFn


class AsyncBoard:
    """The asyncio face of :class:`Board`: the same engine, awaited instead of waited on."""

    def __init__(self, board: Board) -> None:
        self.board = board
        self.dropped = 0  #: SIFs the ``sifs()`` queue had no room for

    @classmethod
    async def open(
        cls, url: str, *, timeout: float = DEFAULT_TIMEOUT, window: int = 1
    ) -> AsyncBoard:
        loop = asyncio.get_running_loop()
        board = await loop.run_in_executor(
            None, lambda: Board.open(url, timeout=timeout, window=window)
        )
        return cls(board)

    functions = Delegate[list[str]]("board")
    properties = Delegate[dict[str, str]]("board")
    transducers = Delegate[list[Transducer] | None]("board")

    async def call(
        self, name: str, payload: bytes = b"", timeout: float | None = None
    ) -> CallResult:
        return await asyncio.wrap_future(self.board.call_future(name, payload, timeout))

    async def read_many(self, name: str, *, progress: ProgressFn | None = None) -> bytes:
        return await asyncio.wrap_future(self.board.read_many_future(name, progress=progress))

    def sifs(
        self, cmd: int | None = None, maxsize: int = 10000
    ) -> asyncio.Queue[tuple[SifReceived, float]]:
        """A queue that receives ``(sif, host_time)``.  Bounded end to end: when the event loop
        or the consumer falls behind, the newest SIFs are dropped and counted (``dropped``);
        at most one hand-over callback is ever pending in the loop."""
        if maxsize <= 0:
            raise ValueError("maxsize must be > 0: an unbounded queue can eat all memory")
        loop = asyncio.get_running_loop()
        queue: asyncio.Queue[tuple[SifReceived, float]] = asyncio.Queue(maxsize)
        pending: deque[tuple[SifReceived, float]] = deque()
        lock = threading.Lock()
        scheduled = [False]
        self.dropped = 0

        def hand_over() -> None:  # in the loop
            with lock:
                items = list(pending)
                pending.clear()
                scheduled[0] = False
            for item in items:
                try:
                    queue.put_nowait(item)
                except asyncio.QueueFull:
                    self.dropped += 1

        def handler(ev: SifReceived, now: float) -> None:  # on the reader thread
            with lock:
                if len(pending) + queue.qsize() >= maxsize:
                    self.dropped += 1
                    return
                pending.append((ev, now))
                if scheduled[0]:
                    return
                scheduled[0] = True
            try:
                loop.call_soon_threadsafe(hand_over)
            except RuntimeError:  # the loop is closed
                pass

        self.board.on_sif(cmd, handler)
        return queue

    async def close(self) -> None:
        await asyncio.get_running_loop().run_in_executor(None, self.board.close)

    async def __aenter__(self) -> AsyncBoard:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()


async def open_board_async(url: str, *, timeout: float = DEFAULT_TIMEOUT) -> AsyncBoard:
    return await AsyncBoard.open(url, timeout=timeout)
