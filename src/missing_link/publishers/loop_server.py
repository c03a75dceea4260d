"""A server on an asyncio loop of its own thread (the web console, the Foxglove view): started
(ready once it listens, or what it met raised in the caller), called into from any thread,
stopped, written once for both."""

from __future__ import annotations

import asyncio
import threading
from typing import Any

from ..logs import ErrorCounts


class LoopServer:
    """A subclass serves in ``_serve(stop)``: it listens, says so with ``_listening(server)``
    and returns once ``stop`` is done.  ``faults``: where a failure of the loop once it runs is
    counted (as ``loop_kind``)."""

    faults: ErrorCounts
    loop_kind = "server loop"

    def _start(self, thread_name: str) -> None:
        """Run the loop on a thread of its own and wait (10 s at most) until the server
        listens; what the loop met before that is raised here."""
        self.port = 0
        self._loop = asyncio.new_event_loop()
        self._ready = threading.Event()
        self._stop: asyncio.Future[None] | None = None
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name=thread_name, daemon=True)
        self._thread.start()
        self._ready.wait(10)
        if self._error is not None:
            raise self._error

    def _call(self, fn: Any, *args: Any) -> None:
        """``fn(*args)`` on the loop, soon (from any thread; nothing once the loop closed)."""
        try:
            self._loop.call_soon_threadsafe(fn, *args)
        except RuntimeError:  # (the loop has closed: shutting down)
            pass

    def close(self) -> None:
        stop = self._stop
        if stop is not None:
            self._call(_finish, stop)
        self._thread.join(5)

    def _run(self) -> None:
        asyncio.set_event_loop(self._loop)
        try:
            self._loop.run_until_complete(self._main())
        except BaseException as e:  # noqa: BLE001 - before it is ready: raised by the constructor;
            if self._ready.is_set():  # later (a bug): counted, its traceback said once
                self.faults.caught(self.loop_kind, e)
            self._error = e
            self._ready.set()
        finally:
            self._loop.close()

    async def _main(self) -> None:
        self._stop = self._loop.create_future()
        await self._serve(self._stop)

    async def _serve(self, stop: asyncio.Future[None]) -> None:
        raise NotImplementedError

    def _listening(self, server: Any) -> None:
        """The server listens: its port (the one asked for, or the one port 0 got), and the
        constructor returns."""
        self.port = int(next(iter(server.sockets)).getsockname()[1])
        self._ready.set()


def _finish(fut: asyncio.Future[None]) -> None:
    if not fut.done():
        fut.set_result(None)
