"""Boards that dial in: ``missing-link run --listen tcp://ADDR:PORT`` accepts boards that connect
to the daemon (an ESP32 on WiFi, as a micro-ROS client dials its agent; board/dial.py).

Theory of operation
-------------------
One thread accepts connections on the listening socket; each new connection gets a thread of
its own, at most ``MAX_PENDING`` at once (more are closed at once and counted: a flood costs
sockets, not threads).  That thread:

1. greets the board when the listener signs (``signed+tcp://...?key=FILE``, required off
   loopback: ``listen_spec.py``): the daemon sends the HELLO and checks the board's CHALLENGE,
   exactly as when it connects to a board (transport/signed.py) - who connects changed, not
   who proves the key (docs/signing.md);
2. reads the board's mapping, properties and descriptors (``Board.handshake``, one deadline),
   on the daemon's I/O loop;
3. hands the board, by the ``board.id`` it states, to ``hand_over`` (the daemon's ``dialin.py``:
   the session of that id, a new one, or a refusal such as ``accept = "known"``).

Anything that goes wrong is one line and a count by kind (``refused``: why), said once per
kind and message (whatever port the board dialed from); nothing a board sends ends a thread.
A board is known by its id, never by its address: the address it came from is only shown
(``address`` in the status).

A board handed over waits for its session in the session's
:class:`~missing_link.daemon.session.link.Mailbox`: the session takes it on its own thread, as it
would open a link by URL.
"""

from __future__ import annotations

import logging
import select
import socket
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from ...errors import MissingLinkError
from ...host.board import Board
from ...host.reactor import Reactor
from ...logs import ErrorCounts
from ...transport.signed import SignedTransport, load_key
from ...transport.sockets import SocketTransport
from ..listen_spec import ListenSpec

log = logging.getLogger(__name__)

#: connections greeted at once; more are closed at once (counted)
MAX_PENDING = 8
_POLL_S = 0.2


@dataclass(frozen=True)
class ListenerContext:
    """What the listener is handed (never the daemon)."""

    reactor: Reactor | None  #: the loop that reads the boards
    timeout: float  #: s per call of the handshake
    handshake_timeout: float  #: s for the greeting's handshake together
    #: a board, greeted and described -> None (a session took it) or why it is refused
    hand_over: Callable[[Board], str | None]


class Listener:
    """Accepts boards on ``spec`` (bound at once: an address in use is a ``MissingLinkError``
    naming it); ``start(ctx)``, ``stop()``, ``status()``."""

    def __init__(self, spec: ListenSpec) -> None:
        self.spec = spec
        self.ctx: ListenerContext | None = None
        self._key = load_key(spec.key_file) if spec.key_file else None
        try:
            self._sock = socket.create_server((spec.host, spec.port), backlog=MAX_PENDING)
        except OSError as e:
            raise MissingLinkError(
                f"cannot listen on {spec.url}: {e.strerror or e} (is another daemon there?)"
            ) from None
        self.port: int = self._sock.getsockname()[1]
        self.url = f"{'signed+' if self._key else ''}tcp://{spec.host}:{self.port}"
        self.faults = ErrorCounts(log, self.url)
        self.accepted = 0  #: connections taken in
        self.handed = 0  #: boards handed to a session
        self.refused: dict[str, int] = {}  #: connections closed, by why
        self._said: set[tuple[str, str]] = set()
        self._pending = 0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._accept_loop, name="listener", daemon=True)

    def start(self, ctx: ListenerContext) -> None:
        self.ctx = ctx
        self._thread.start()

    def stop(self, timeout: float = 1.0) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout)
        self._sock.close()

    def _accept_loop(self) -> None:
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select([self._sock], [], [], _POLL_S)
                if not ready:
                    continue
                sock, peer = self._sock.accept()
            except (OSError, ValueError) as e:  # (closed by stop(); else out of descriptors)
                if not self._stop.is_set():
                    self._refuse("accept failed", f"{getattr(e, 'strerror', None) or e}", "-")
                    self._stop.wait(_POLL_S)
                continue
            try:
                self._take(sock, f"tcp://{peer[0]}:{peer[1]}")
            except Exception as e:  # noqa: BLE001 - (no thread to start: said, counted; the
                sock.close()  # listener goes on)
                self.faults.caught("accept", e, "taking a board that dialed in")

    def _take(self, sock: socket.socket, address: str) -> None:
        """A connection to greet on a thread of its own, unless MAX_PENDING are greeted."""
        with self._lock:
            busy = self._pending >= MAX_PENDING
            if not busy:
                self._pending += 1
        if busy:
            sock.close()
            self._refuse("busy", f"{MAX_PENDING} connections greeted already", address)
            return
        self.accepted += 1
        try:
            threading.Thread(target=self._serve_one, args=(sock, address),
                             name=f"dial-in:{address}", daemon=True).start()  # fmt: skip
        except BaseException:  # (broad, raised again: the slot is given back)
            with self._lock:
                self._pending -= 1
            raise

    def _serve_one(self, sock: socket.socket, address: str) -> None:
        try:
            board = self._greet(sock, address)
            if board is None:
                return
            assert self.ctx is not None
            why = self.ctx.hand_over(board) if not self._stop.is_set() else "the daemon stops"
            if why is None:
                self.handed += 1
                return
            board.close()
            self._refuse("refused", why, address)
        except Exception as e:  # noqa: BLE001 - nothing a board sends may end the listener:
            sock.close()  # counted by kind, its traceback said once
            self.faults.caught("dial-in", e, f"a board that dialed in from {address}")
        finally:
            with self._lock:
                self._pending -= 1

    def _greet(self, sock: socket.socket, address: str) -> Board | None:
        """The board on ``sock`` greeted (signed) and described, or None (said, counted)."""
        try:
            transport: Any = SocketTransport(address, sock)
            if self._key is not None:
                transport = SignedTransport(transport, self._key)
        except MissingLinkError as e:
            sock.close()
            self._refuse("greeting failed", str(e), address)
            return None
        ctx = self.ctx
        assert ctx is not None  # (started)
        board = Board(transport, timeout=ctx.timeout, reactor=ctx.reactor, faults=self.faults)
        try:
            board.handshake(deadline=board.clock.monotonic() + ctx.handshake_timeout)
        except MissingLinkError as e:
            board.close()
            self._refuse("handshake failed", str(e), address)
            return None
        return board

    def _refuse(self, kind: str, why: str, address: str) -> None:
        said = (kind, why.replace(address, "ADDRESS"))  # (a board dials from a new port)
        with self._lock:
            self.refused[kind] = self.refused.get(kind, 0) + 1
            first = said not in self._said and len(self._said) < 256
            if first:
                self._said.add(said)
        # the same refusal again (a board that redials every few seconds) is said once
        log.log(logging.WARNING if first else logging.DEBUG, "%s: %s: %s (%s)", self.url, kind,
                why, address)  # fmt: skip

    def status(self) -> dict[str, Any]:
        """For ``Daemon.publisher_status`` and ``/diagnostics``: what came in, and what not."""
        refused = sum(self.refused.values())
        return {
            "publisher": "listener",
            "level": 1 if self.faults.total else 0,
            "message": f"listening on {self.url}",
            "accepted": self.accepted,
            "handed": self.handed,
            "refused": refused,
            "refused_kinds": ", ".join(f"{k} x{n}" for k, n in sorted(self.refused.items())),
            **self.faults.to_json(),
        }
