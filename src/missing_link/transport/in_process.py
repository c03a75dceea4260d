"""``memory://NAME``: in-process links for tests and embedding (the virtual bus).

``memory_pair()`` gives two connected ends.  A virtual board serves a name with
``MemoryListener(name)``; ``open_transport("memory://name")`` connects to it.
"""

from __future__ import annotations

import threading
from collections import deque
from urllib.parse import urlsplit

from ..errors import BadURL, TransportBroken, TransportClosed
from .base import Transport


class _Pipe:
    def __init__(self) -> None:
        self.chunks: deque[bytes] = deque()
        self.cond = threading.Condition()
        self.writer_closed = False


class MemoryTransport(Transport):
    def __init__(self, url: str, rx: _Pipe, tx: _Pipe) -> None:
        self.url = url
        self._rx = rx
        self._tx = tx
        self._closed = False

    wakes_on_close = True

    def read(self, timeout: float | None) -> bytes:
        if self._closed:
            raise TransportClosed(f"{self.url}: transport closed on this side")
        with self._rx.cond:
            if not self._rx.chunks and not self._rx.writer_closed:
                self._rx.cond.wait(timeout)
            if self._rx.chunks:
                data = b"".join(self._rx.chunks)
                self._rx.chunks.clear()
                return data
            if self._closed:
                raise TransportClosed(f"{self.url}: transport closed on this side")
            if self._rx.writer_closed:
                raise TransportBroken(f"{self.url}: the other side closed the link")
            return b""

    def write(self, data: bytes) -> None:
        if self._closed:
            raise TransportClosed(f"{self.url}: transport closed on this side")
        with self._tx.cond:
            if self._tx.writer_closed:
                raise TransportBroken(f"{self.url}: the other side closed the link")
            self._tx.chunks.append(bytes(data))
            self._tx.cond.notify_all()

    def poke(self) -> None:
        with self._rx.cond:
            self._rx.cond.notify_all()

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        for pipe in (self._tx, self._rx):
            with pipe.cond:
                pipe.writer_closed = True
                pipe.cond.notify_all()


def memory_pair(name: str = "pair") -> tuple[MemoryTransport, MemoryTransport]:
    a, b = _Pipe(), _Pipe()
    url = f"memory://{name}"
    return MemoryTransport(url, a, b), MemoryTransport(url, b, a)


class MemoryListener:
    """Accepts ``memory://NAME`` connections, one at a time, for a virtual board."""

    _listeners: dict[str, MemoryListener] = {}
    _lock = threading.Lock()

    def __init__(self, name: str) -> None:
        with self._lock:
            if name in self._listeners:
                raise BadURL(f"memory://{name} is already served")
            self._listeners[name] = self
        self.name = name
        self.url = f"memory://{name}"
        self._pending: deque[MemoryTransport] = deque()
        self._cond = threading.Condition()

    def accept(self, timeout: float | None) -> MemoryTransport | None:
        with self._cond:
            if not self._pending:
                self._cond.wait(timeout)
            return self._pending.popleft() if self._pending else None

    def _connect(self) -> MemoryTransport:
        client, server = memory_pair(self.name)
        with self._cond:
            self._pending.append(server)
            self._cond.notify_all()
        return client

    def close(self) -> None:
        with self._lock:
            self._listeners.pop(self.name, None)

    @classmethod
    def connect(cls, url: str) -> MemoryTransport:
        name = urlsplit(url).netloc
        with cls._lock:
            listener = cls._listeners.get(name)
        if listener is None:
            raise TransportBroken(f"{url}: no virtual board serves this name")
        return listener._connect()


def open_memory(url: str, query: dict[str, str]) -> MemoryTransport:
    return MemoryListener.connect(url)
