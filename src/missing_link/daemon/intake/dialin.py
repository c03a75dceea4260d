"""Boards that dial in (``run --listen``): the listener (listener.py) greets and describes each,
and here it goes to its session by the ``board.id`` it states, never by the address it came
from.

Theory of operation
-------------------
Each id has the sessions of the boards that dialed in with it (one, normally), each with its
:class:`~missing_link.daemon.session.link.Mailbox`.  A board that states id X goes:

* refused, when it states no id (or one that is not 1..64 printable characters), or when
  ``[daemon] accept = "known"`` and no ``[boards.NAME] id = "X"`` names it (the board dials
  again later: board/dial.py's backoff);
* to a session of X whose link states the same boot (the same ``clock.epoch``: the board lost
  its connection and dialed again before the old one was noticed), once that old link has
  failed a probe (``a2jEcho`` with a fresh nonce, ``PROBE_S``): a board that dials again has
  given its old connection up, so a link that still answers is another board's.  Ids and
  epochs are public (the status shows them): a claim alone never closes a live link, so a
  board that states another's id and epoch is treated as the next case (docs/security.md);
* to a session of X that has no link now (the board went and came back: a restart, a new
  address): it comes back under the same name, topics and configuration;
* when every session of X has a link that seems alive (and is another boot, or answered the
  probe): the old link of a board that restarted may still look alive (a half-open TCP
  connection: the session notices within its ``link_timeout``), so the new board waits that
  long for one of them to go.  If
  none goes, two boards state X: the new one gets a session of its own (``NAME_2``), and both
  are shown with the warning (claims.py);
* else to a new session, named by the config's ``[boards.NAME] id``, else by its
  ``board.name``; it keeps that name when the board comes back.

Ids the config does not name are bounded (issue 43.4: 1,000 ids that dialed once left 1,008
threads, 143 MB and a third of a core behind): at most ``[daemon] dialin_max`` of them are held
at once (a new one beyond is refused, saying so: the listener says it once), and the session
of one whose board has been gone ``[daemon] dialin_expire`` s is removed with its name
(``sweep``, from the daemon's diagnostics thread; said in the log).  A configured id is the
operator's: its session stays and counts against nothing.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Callable
from typing import Any

from ...errors import MissingLinkError
from ...host.board import Board
from ...host.clock import SYSTEM_CLOCK, Clock
from ...host.reactor import Reactor
from ..config import BOARD_ID, BoardSpec, Config
from ..listen_spec import ListenSpec
from ..session.link import Mailbox
from ..session.session import BoardSession
from ..session.status import SessionState
from .listener import Listener, ListenerContext

log = logging.getLogger(__name__)

#: s between looks at an old link while a new board of its id waits for it to go
_LOOK_S = 0.05
#: s an old link of the same boot has to answer a probe before a new one replaces it
PROBE_S = 1.0

#: (spec, mailbox) -> a started session (MissingLinkError once the daemon stops)
AddSession = Callable[[BoardSpec, Mailbox], BoardSession]
#: sessions the daemon no longer keeps -> None (stopped, their names released)
Forget = Callable[[list[BoardSession]], None]


def _live(s: BoardSession) -> bool:
    b = s.board
    return s.state == SessionState.UP and b is not None and b.alive


Held = list[tuple[BoardSession, Mailbox]]


def _same_boot(held: Held, epoch: str, answered: list[Board]) -> tuple[Mailbox, Board] | None:
    """A link of a session of the id (its live one, or one waiting in its box) that states
    ``epoch`` and has not answered a probe yet: (its box, its board)."""
    if not epoch:
        return None
    for session, box in held:
        waiting, old = box.waiting, session.board
        if waiting is not None and waiting.properties.get("clock.epoch") == epoch:
            found: Board = waiting
        elif old is not None and _live(session) and session.epoch == epoch:
            found = old
        else:
            continue
        if not any(found is b for b in answered):
            return box, found
    return None


def _place(held: Held, board: Board) -> str | None:
    """``board`` to a session of its id that has no link: "" when one took it, why not when
    the daemon stops, None when every session of the id has a link (or none is there)."""
    for session, box in held:
        if not _live(session) and box.waiting is None:
            return "" if box.put(board) else "the daemon stops"
    return None


def answers(board: Board, timeout: float = PROBE_S) -> bool:
    """The link answers an ``a2jEcho`` of a fresh nonce in time: it is alive (its board may be
    anyone that states the id; a link that cannot answer is dead, or was never a board's)."""
    nonce = os.urandom(8)
    try:
        result = board.call("a2jEcho", nonce, timeout)
    except MissingLinkError:
        return False
    return result.code == 0xBA and result.payload == nonce


class DialIns:
    """The listener on ``spec`` (bound here: a taken address fails at once) and the sessions
    of the boards that dialed in; ``start(reactor)``, ``stop()``, ``status()``."""

    def __init__(
        self,
        config: Config,
        spec: ListenSpec,
        add_session: AddSession,
        clock: Clock = SYSTEM_CLOCK,
        forget: Forget = lambda sessions: None,
    ) -> None:
        self.config = config
        self.clock = clock  #: the daemon's (its boards' links are on the reactor's, the same)
        self._add_session = add_session
        self._forget = forget
        self._by_id: dict[str, Held] = {}
        self._gone: dict[int, float] = {}  # id() of a session of an unknown id -> gone since
        self.expired = 0  #: sessions of unknown ids removed after dialin_expire
        #: does a link answer (its board alive)?  (tests hand fakes their own)
        self.probe: Callable[[Board], bool] = answers
        self._lock = threading.Lock()
        self.listener = Listener(spec, clock)

    def start(self, reactor: Reactor | None) -> None:
        defaults = BoardSpec(url="")
        self.listener.start(
            ListenerContext(reactor, defaults.timeout, defaults.handshake_timeout, self.hand_over)
        )

    def status(self) -> dict[str, Any]:
        with self._lock:
            unknown = sum(len(h) for i, h in self._by_id.items() if self._unknown(i))
        return {**self.listener.status(), "unknown_ids": unknown, "expired": self.expired}

    def _unknown(self, board_id: str) -> bool:
        return self.config.name_of_id(board_id) is None

    def sweep(self) -> None:
        """Remove the sessions of unknown ids whose boards have been gone ``dialin_expire`` s
        (a board that comes back later is a new board: a new session, its name again)."""
        now, expire = self.clock.monotonic(), self.config.dialin_expire
        out: list[tuple[str, BoardSession]] = []
        with self._lock:
            for board_id, held in list(self._by_id.items()):
                if not self._unknown(board_id):
                    continue
                for session, box in list(held):
                    key = id(session)
                    if _live(session) or box.waiting is not None:
                        self._gone.pop(key, None)
                    elif now - self._gone.setdefault(key, now) >= expire:
                        held.remove((session, box))
                        self._gone.pop(key, None)
                        box.close()
                        out.append((board_id, session))
                if not held:
                    del self._by_id[board_id]
            self.expired += len(out)
        for board_id, session in out:
            why = "an id the config does not name: [daemon] dialin_expire"
            log.info("%s (board.id %s) gone %g s: its session is removed (%s)", session.name,
                     board_id, expire, why)  # fmt: skip
        if out:
            self._forget([s for _i, s in out])

    def hand_over(self, board: Board) -> str | None:
        """Give ``board`` to its session (see the theory above); None, or why it is refused."""
        props = board.properties
        board_id = props.get("board.id") or props.get("board.serial", "")
        if not board_id:
            return "it states no board.id (nor board.serial): a board is known by its id"
        if not BOARD_ID.match(board_id):  # (untrusted: it names a session, a URL, a warning)
            return f"board.id {board_id[:80]!r} is not 1..64 printable ASCII without spaces"
        name = self.config.name_of_id(board_id)
        if name is None and self.config.accept == "known":
            return (
                f'board.id {board_id!r} is not in the config (accept = "known"): name it with '
                f'[boards.NAME] id = "{board_id}"'
            )
        if name is None and self._full(board_id):
            return (
                f"{self.config.dialin_max} boards of ids not in the config are held already "
                f"([daemon] dialin_max); one that left is forgotten "
                f"{self.config.dialin_expire:g} s later ([daemon] dialin_expire), or name "
                f'this one: [boards.NAME] id = "{board_id}"'
            )
        epoch = props.get("clock.epoch", "")
        with self._lock:
            waits = [s.spec.link_timeout for s, _box in self._by_id.get(board_id, [])]
        deadline = self.clock.monotonic() + max(waits, default=0.0) + 0.5
        answered: list[Board] = []  # links of its boot that answered: another board's
        while True:
            with self._lock:
                held = self._by_id.get(board_id, [])
                claim = _same_boot(held, epoch, answered)
                if claim is None:
                    verdict = _place(held, board)
                    if verdict is not None:
                        return verdict or None
                    if not held or self.clock.monotonic() >= deadline:
                        return self._new_session(board_id, name, board)
            if claim is None:
                time.sleep(_LOOK_S)
            elif self.probe(claim[1]):  # (outside the lock: a round trip)
                answered.append(claim[1])
            else:
                verdict = self._replace(board_id, epoch, answered, claim, board)
                if verdict is not None:
                    return verdict or None

    def _full(self, board_id: str) -> bool:
        """A new unknown id would be one more than ``dialin_max`` (one known already is not)."""
        with self._lock:
            if board_id in self._by_id:
                return False
            held = sum(len(h) for i, h in self._by_id.items() if self._unknown(i))
        return held >= self.config.dialin_max

    def _replace(
        self,
        board_id: str,
        epoch: str,
        answered: list[Board],
        claim: tuple[Mailbox, Board],
        board: Board,
    ) -> str | None:
        """The old link of ``claim`` did not answer: ``board`` takes its place, if it is still
        there ("", or why not); None when things moved meanwhile (look again)."""
        with self._lock:
            if _same_boot(self._by_id.get(board_id, []), epoch, answered) != claim:
                return None
            box, old = claim
            if not box.put(board):
                return "the daemon stops"
        old.close()  # (dead: the same boot dialed again; a waiting one the box closed)
        return ""

    def _new_session(self, board_id: str, name: str | None, board: Board) -> str | None:
        """Under the lock: a session of its own for ``board``."""
        box = Mailbox()
        box.put(board)
        spec = BoardSpec(url=f"dial://{board_id}", name=name)
        try:
            session = self._add_session(spec, box)
        except MissingLinkError:  # (the daemon stops)
            box.close()
            return "the daemon stops"
        self._by_id.setdefault(board_id, []).append((session, box))
        return None

    def stop(self) -> None:
        """The daemon stops: no more boards are taken in (their sessions close their own)."""
        self.listener.stop()
