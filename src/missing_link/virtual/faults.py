"""A fault-injecting relay between a host and a board: corruption, delay, loss, a black hole.

``FaultRelay(upstream_url)`` listens on ``tcp://127.0.0.1:0`` (or ``unix:///path``); each host
that connects gets its own connection to the board at ``upstream_url`` (any board URL: tcp,
unix, serial/pty, ...), and bytes are forwarded both ways through the faults:

* ``corrupt``: per-byte probability of flipping one random bit (positions drawn with geometric
  gaps, so a low rate costs nothing per byte);
* ``drop``: per-read probability of losing a whole chunk of bytes;
* ``delay_s``: every chunk is held this long (latency, not a throughput limit);
* ``blackhole_after`` / ``blackhole_for``: after that many seconds of a connection, forward
  nothing either way (both sockets stay open: a half-open link, a frozen board, a pulled
  cable behind a USB-serial bridge), for ``blackhole_for`` s (None: for ever); ``blackhole()``
  does it on demand.

Counters say what was done (``corrupted``, ``dropped_bytes``, ``blackholed_bytes``).  Use it from
tests (``with FaultRelay(url, Faults(corrupt=1e-3)) as relay: ... relay.url``) or from the CLI:
``missing-link relay URL --corrupt 1e-3 --delay-ms 5 --blackhole-after 10``.  It only ever
listens on the address it is given (loopback by default).
"""

from __future__ import annotations

import math
import os
import random
import select
import socket
import threading
import time
from collections import deque
from dataclasses import dataclass
from urllib.parse import urlsplit

from ..errors import TransportBroken, TransportClosed
from ..transport import Transport, open_transport
from .listen import listen_socket

_TICK = 0.01


@dataclass
class Faults:
    corrupt: float = 0.0  #: per-byte probability of a flipped bit
    drop: float = 0.0  #: per-chunk probability of losing it
    delay_s: float = 0.0
    blackhole_after: float | None = None  #: s after a connection starts
    blackhole_for: float | None = None  #: s (None: until the connection ends)
    seed: int = 0

    def check(self) -> Faults:
        for name in ("corrupt", "drop"):
            p = getattr(self, name)
            if not 0.0 <= p < 1.0:
                raise ValueError(f"{name} = {p}: a probability in [0, 1)")
        for name in ("delay_s", "blackhole_after", "blackhole_for"):
            v = getattr(self, name)
            if v is not None and not 0.0 <= v <= 86400:
                raise ValueError(f"{name} = {v}: seconds in 0..86400")
        return self


class _Corrupter:
    def __init__(self, p: float, rng: random.Random) -> None:
        self.p = p
        self.rng = rng
        self.flipped = 0
        self._gap = self._next_gap()

    def set_p(self, p: float) -> None:
        self.p = p
        self._gap = self._next_gap()

    def _next_gap(self) -> int:
        if self.p <= 0:
            return 1 << 62
        return int(math.log(1.0 - self.rng.random()) / math.log(1.0 - self.p))

    def __call__(self, data: bytes) -> bytes:
        if self._gap >= len(data):
            self._gap -= len(data)
            return data
        out = bytearray(data)
        i = self._gap
        while i < len(out):
            out[i] ^= 1 << self.rng.randrange(8)
            self.flipped += 1
            i += 1 + self._next_gap()
        self._gap = i - len(out)
        return bytes(out)


#: what a relay counts (``counters()``), in its order
_COUNTERS = ("connections", "forwarded", "corrupted", "dropped_bytes", "blackholed_bytes")


class FaultRelay:
    def __init__(
        self, upstream: str, faults: Faults | None = None, listen: str = "tcp://127.0.0.1:0"
    ) -> None:
        self.upstream = upstream
        self.faults = (faults or Faults()).check()
        self.rng = random.Random(self.faults.seed)
        self._listener = _listen(listen)
        if self._listener.family == socket.AF_UNIX:
            self.url = f"unix://{self._listener.getsockname()}"
        else:
            host, port = self._listener.getsockname()[:2]
            self.url = f"tcp://{host}:{port}"
        self._stop = threading.Event()
        self._forced_hole = threading.Event()
        self._threads: list[threading.Thread] = []
        self._lock = threading.Lock()
        self.connections = 0
        self.forwarded = 0
        self.corrupted = 0
        self.dropped_bytes = 0
        self.blackholed_bytes = 0
        self.errors: list[str] = []  #: upstream failures, one line each
        self._corrupters: list[_Corrupter] = []

    # ---- control ------------------------------------------------------------------------------
    def start(self) -> FaultRelay:
        t = threading.Thread(target=self._accept_loop, name=f"relay:{self.url}", daemon=True)
        t.start()
        self._threads.append(t)
        return self

    def blackhole(self, on: bool = True) -> None:
        """Forward nothing either way (connections stay open) until ``blackhole(False)``."""
        if on:
            self._forced_hole.set()
        else:
            self._forced_hole.clear()

    def set_corrupt(self, p: float) -> None:
        """Change the bit-flip probability, live connections included."""
        self.faults.corrupt = p
        Faults.check(self.faults)
        for c in list(self._corrupters):
            c.set_p(p)

    def stop(self) -> None:
        self._stop.set()
        try:
            self._listener.close()
        except OSError:
            pass
        for t in self._threads:
            t.join(2.0)
        if self._listener.family == socket.AF_UNIX:
            try:
                os.unlink(urlsplit(self.url).path)
            except OSError:
                pass

    def __enter__(self) -> FaultRelay:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def counters(self) -> dict[str, int]:
        return {k: getattr(self, k) for k in _COUNTERS}

    # ---- the relay ----------------------------------------------------------------------------
    def _accept_loop(self) -> None:
        self._listener.settimeout(0.1)
        while not self._stop.is_set():
            try:
                client, _ = self._listener.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            try:
                board = open_transport(self.upstream)
            except Exception as e:  # noqa: BLE001 - one line, and the host sees a closed link
                self.errors.append(f"{self.upstream}: {e}")
                client.close()
                continue
            self.connections += 1
            t = threading.Thread(
                target=self._serve, args=(client, board), name="relay-conn", daemon=True
            )
            t.start()
            self._threads.append(t)

    def _serve(self, client: socket.socket, board: Transport) -> None:
        f = self.faults
        started = time.monotonic()
        down: deque[tuple[float, bytes]] = deque()  # board -> host, (due, bytes)
        up: deque[tuple[float, bytes]] = deque()  # host -> board
        corrupt_down = _Corrupter(f.corrupt, random.Random(self.rng.random()))
        corrupt_up = _Corrupter(f.corrupt, random.Random(self.rng.random()))
        self._corrupters[:] = [c for c in self._corrupters[-8:]] + [corrupt_down, corrupt_up]
        board_fd = getattr(board, "_fd", None)  # fd transports: wait on both at once
        try:
            while not self._stop.is_set():
                due = min([q[0][0] for q in (up, down) if q], default=time.monotonic() + _TICK)
                wait = max(0.0, min(_TICK, due - time.monotonic()))
                fds = [client] if board_fd is None else [client, board_fd]
                ready, _, _ = select.select(fds, [], [], wait)
                now = time.monotonic()
                hole = self._forced_hole.is_set() or _in_window(now - started, f)
                if client in ready:
                    data = client.recv(65536)
                    if not data:
                        return  # the host went away
                    self._take(data, hole, up, corrupt_up, now)
                if board_fd is None or board_fd in ready:
                    data = board.read(0.0)
                    if data:
                        self._take(data, hole, down, corrupt_down, now)
                now = time.monotonic()
                while up and up[0][0] <= now:
                    board.write(up.popleft()[1])
                while down and down[0][0] <= now:
                    client.sendall(down.popleft()[1])
        except (TransportBroken, TransportClosed, OSError) as e:
            self.errors.append(f"{self.upstream}: {e}")
        finally:
            client.close()
            board.close()

    def _take(
        self,
        data: bytes,
        hole: bool,
        queue: deque[tuple[float, bytes]],
        corrupt: _Corrupter,
        now: float,
    ) -> None:
        with self._lock:
            if hole:
                self.blackholed_bytes += len(data)
                return
            if self.faults.drop and self.rng.random() < self.faults.drop:
                self.dropped_bytes += len(data)
                return
            before = corrupt.flipped
            data = corrupt(data)
            self.corrupted += corrupt.flipped - before
            self.forwarded += len(data)
        queue.append((now + self.faults.delay_s, data))


def _in_window(elapsed: float, f: Faults) -> bool:
    if f.blackhole_after is None or elapsed < f.blackhole_after:
        return False
    return f.blackhole_for is None or elapsed < f.blackhole_after + f.blackhole_for


def _listen(url: str) -> socket.socket:
    """The relay's listening socket (listen.py: tcp, with any free port when none is given, or
    unix); TransportBroken when it cannot be bound."""
    if url.startswith("tcp://") and urlsplit(url).port is None:
        url += ":0"
    try:
        sock, _bound = listen_socket(url, 4)
    except OSError as e:
        raise TransportBroken(f"cannot listen on {url}: {e.strerror}") from None
    return sock
