"""Boards that dial in (``run --listen``): the listener (listener.py) greets and describes each,
and here it goes to its session by the ``board.id`` it states, never by the address it came
from.

Theory of operation
-------------------
Each id has the sessions of the boards that dialed in with it (one, normally), each with its
:class:`~missing_link.daemon.listener.Mailbox`.  A board that states id X goes:

* refused, when it states no id (or one that is not 1..64 printable characters), or when
  ``[daemon] accept = "known"`` and no ``[boards.NAME] id = "X"`` names it (the board dials
  again later: board/dial.py's backoff);
* to a session of X whose link is the same boot of the same board (the same ``clock.epoch``:
  it lost its connection and dialed again before the old one was noticed): that old link is
  closed and the session takes the new one at once;
* to a session of X that has no link now (the board went and came back: a restart, a new
  address): it comes back under the same name, topics and configuration;
* when every session of X has a link that seems alive and is another boot: the old link of a
  board that restarted may still look alive (a half-open TCP connection: the session notices
  within its ``link_timeout``), so the new board waits that long for one of them to go.  If
  none goes, two boards state X: the new one gets a session of its own (``NAME_2``), and both
  are shown with the warning (claims.py);
* else to a new session, named by the config's ``[boards.NAME] id``, else by its
  ``board.name``; it keeps that name when the board comes back.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

from ..errors import MissingLinkError
from ..host.board import Board
from ..host.reactor import Reactor
from .config import BOARD_ID, BoardSpec, Config
from .listen_spec import ListenSpec
from .listener import Listener, ListenerContext, Mailbox
from .session import UP, BoardSession

#: s between looks at an old link while a new board of its id waits for it to go
_LOOK_S = 0.05

#: (spec, mailbox) -> a started session (MissingLinkError once the daemon stops)
AddSession = Callable[[BoardSpec, Mailbox], BoardSession]


def _live(s: BoardSession) -> bool:
    b = s.board
    return s.state == UP and b is not None and b.alive


def _place(held: list[tuple[BoardSession, Mailbox]], epoch: str, board: Board) -> str | None:
    """``board`` to a session of its id: "" when one took it, why not when the daemon stops,
    None when every session of the id has a link, or a board waiting, of another boot (or
    there is none)."""
    for session, box in held:
        waiting = box.waiting
        if epoch and (
            (waiting is not None and waiting.properties.get("clock.epoch") == epoch)
            or (_live(session) and session.epoch == epoch)
        ):
            old = session.board if _live(session) else None
            if not box.put(board):
                return "the daemon stops"
            if old is not None:
                old.close()  # (the same boot dialed again: its old connection is dead)
            return ""
    for session, box in held:
        if not _live(session) and box.waiting is None:
            return "" if box.put(board) else "the daemon stops"
    return None


class DialIns:
    """The listener on ``spec`` (bound here: a taken address fails at once) and the sessions
    of the boards that dialed in; ``start(reactor)``, ``stop()``, ``status()``."""

    def __init__(self, config: Config, spec: ListenSpec, add_session: AddSession) -> None:
        self.config = config
        self._add_session = add_session
        self._by_id: dict[str, list[tuple[BoardSession, Mailbox]]] = {}
        self._lock = threading.Lock()
        self.listener = Listener(spec)

    def start(self, reactor: Reactor | None) -> None:
        defaults = BoardSpec(url="")
        self.listener.start(
            ListenerContext(reactor, defaults.timeout, defaults.handshake_timeout, self.hand_over)
        )

    def status(self) -> dict[str, Any]:
        return self.listener.status()

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
        epoch = props.get("clock.epoch", "")
        with self._lock:
            waits = [s.spec.link_timeout for s, _box in self._by_id.get(board_id, [])]
        deadline = time.monotonic() + max(waits, default=0.0) + 0.5
        while True:
            with self._lock:
                held = self._by_id.get(board_id, [])
                verdict = _place(held, epoch, board)
                if verdict is not None:
                    return verdict or None
                if not held or time.monotonic() >= deadline:
                    return self._new_session(board_id, name, board)
            time.sleep(_LOOK_S)

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
