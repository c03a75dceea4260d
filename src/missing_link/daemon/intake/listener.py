"""Boards that dial in: ``missing-link run --listen tcp://ADDR:PORT`` accepts boards that connect
to the daemon (an ESP32 on WiFi, as a micro-ROS client dials its agent; board/dial.py).

Theory of operation
-------------------
One thread accepts connections on the listening socket; each new connection gets a thread of
its own, at most ``MAX_PENDING`` at once and ``PER_ADDRESS`` from one address (a flood costs
sockets, not threads).  A connection holds its place only while it speaks J2A: one that has
not answered the daemon's first request within ``FIRST_REPLY_S`` is closed ("silent"), and when
the places are full a newcomer takes the place of the oldest connection that has not answered
in ``GRACE_S`` ("evicted"; refused "busy" when none is such: a connection always has that long
to answer, so a flood that opens again at once what is closed cannot turn a board out before
its first reply).  Eight idle
connections kept a real board out for as long as they lasted before (issue 43.9); now a board
that dials answers within a round trip and gets in, and what was idle is gone within a second
or two.  That thread:

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
from ...host.clock import SYSTEM_CLOCK, Clock
from ...host.reactor import Reactor
from ...logs import ErrorCounts
from ...transport.signed import SignedTransport, load_key
from ...transport.sockets import SocketTransport
from ..listen_spec import ListenSpec

log = logging.getLogger(__name__)

#: connections greeted at once, and from one address (a newcomer takes the place of the oldest
#: that has not answered; when all answer, it is closed at once: counted)
MAX_PENDING = 8
PER_ADDRESS = 4
#: s a connection has to answer the daemon's first request (a board that dials answers at once)
FIRST_REPLY_S = 2.0
#: s a connection that has not answered yet keeps its place against newcomers
GRACE_S = 0.5
_POLL_S = 0.2


@dataclass
class _Greeting:
    """One connection being greeted: where from, since when, its board once it has one."""

    sock: socket.socket
    host: str
    since: float
    board: Board | None = None
    dropped: bool = False  #: closed by the listener (silent, or evicted): its place is free

    def answered(self) -> bool:
        """It has answered a request (J2A, not junk): a board, not an idle connection."""
        board = self.board
        return board is not None and board.link_stats().replies > 0


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

    def __init__(self, spec: ListenSpec, clock: Clock = SYSTEM_CLOCK) -> None:
        self.spec = spec
        self.clock = clock  #: the daemon's: a greeting's grace and first-reply deadline
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
        self._greeting: dict[int, _Greeting] = {}  # by id(): the connections being greeted
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
                self._drop_silent()
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
                self._take(sock, str(peer[0]), f"tcp://{peer[0]}:{peer[1]}")
            except Exception as e:  # noqa: BLE001 - (no thread to start: said, counted; the
                sock.close()  # listener goes on)
                self.faults.caught("accept", e, "taking a board that dialed in")

    def _take(self, sock: socket.socket, host: str, address: str) -> None:
        """A connection to greet on a thread of its own, in a place of its own (see above)."""
        now = self.clock.monotonic()
        with self._lock:
            victim, busy = self._place(host, now)
            entry = _Greeting(sock, host, now)
            if not busy:
                self._greeting[id(entry)] = entry
        if victim is not None:
            _drop(victim)
            self._refuse("evicted", "it had not answered; a newcomer needed its place", "-")
        if busy:
            sock.close()
            self._refuse("busy", busy, address)
            return
        self.accepted += 1
        try:
            threading.Thread(target=self._serve_one, args=(entry, address),
                             name=f"dial-in:{address}", daemon=True).start()  # fmt: skip
        except BaseException:  # (broad, raised again: the place is given back)
            with self._lock:
                self._greeting.pop(id(entry), None)
            raise

    def _place(self, host: str, now: float) -> tuple[_Greeting | None, str]:
        """(Under the lock.)  Room for a connection from ``host``: (the greeting whose place
        it takes, or None; "" or why it is refused)."""
        held = [g for g in self._greeting.values() if not g.dropped]
        mine = [g for g in held if g.host == host]
        if len(mine) >= PER_ADDRESS:
            pool, full = mine, f"{PER_ADDRESS} connections from {host} greeted already"
        elif len(held) >= MAX_PENDING:
            pool, full = held, f"{MAX_PENDING} connections greeted already"
        else:
            return None, ""
        if len(self._greeting) >= 2 * MAX_PENDING:  # (dropped ones not yet gone: no more)
            return None, full
        silent = [g for g in pool if now - g.since >= GRACE_S and not g.answered()]
        if not silent:
            return None, full + ", each answering"
        victim = min(silent, key=lambda g: g.since)
        victim.dropped = True
        return victim, ""

    def _drop_silent(self) -> None:
        """Close the connections that have not answered within FIRST_REPLY_S."""
        now = self.clock.monotonic()
        with self._lock:
            due = [g for g in self._greeting.values() if now - g.since > FIRST_REPLY_S]
            late = [g for g in due if not g.dropped and not g.answered()]
            for g in late:
                g.dropped = True
        for g in late:
            _drop(g)
            why = f"no answer to the first request within {FIRST_REPLY_S:g} s"
            self._refuse("silent", why, "-")

    def _serve_one(self, entry: _Greeting, address: str) -> None:
        sock = entry.sock
        try:
            board = self._greet(entry, address)
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
                self._greeting.pop(id(entry), None)

    def _greet(self, entry: _Greeting, address: str) -> Board | None:
        """The board on ``entry``'s socket greeted (signed) and described, or None (said,
        counted)."""
        sock = entry.sock
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
        with self._lock:
            entry.board = board
            dropped = entry.dropped
        try:
            if dropped:  # (its place was taken meanwhile)
                raise MissingLinkError("closed: it had not answered")
            board.handshake(deadline=board.clock.monotonic() + ctx.handshake_timeout)
        except MissingLinkError as e:
            board.close()
            if not entry.dropped:  # (a dropped one is counted as such)
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
        with self._lock:
            greeting = sum(not g.dropped for g in self._greeting.values())
        return {
            "publisher": "listener",
            "level": 1 if self.faults.total else 0,
            "message": f"listening on {self.url}",
            "accepted": self.accepted,
            "greeting": greeting,  #: connections being greeted now
            "handed": self.handed,
            "refused": refused,
            "refused_kinds": ", ".join(f"{k} x{n}" for k, n in sorted(self.refused.items())),
            **self.faults.to_json(),
        }


def _drop(g: _Greeting) -> None:
    """End a greeting from outside its thread: its reads see the end at once."""
    try:
        g.sock.shutdown(socket.SHUT_RDWR)
    except OSError:  # (closed already)
        pass
