"""What a board session may know of the daemon: plain values and callables, never the daemon.

A :class:`~missing_link.daemon.session.session.BoardSession` is handed one ``SessionContext`` (as
httpcore hands a connection a callback, never its pool): a few values and two narrow
interfaces, :class:`Claims` (its board name, ``board.id`` and message type names, held
daemon-wide, so two boards never merge or clash) and :class:`Faces` (declaring topics,
publishing updates, offering and withdrawing command topics, its configuration, log and
description, to every face).  The session hands its own children narrower ones still.  Tests
build one from lists and fakes (``tests/test_daemon_parts.py``); the daemon builds one from its
claims and its fan-out (:meth:`~missing_link.daemon.service.Daemon.session_context`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

from ...descriptors import Transducer
from ...host.board_log import LogLine
from ...host.clock import SYSTEM_CLOCK, Clock
from ...host.config import ConfigKey, Value
from ...host.reactor import Reactor
from ...ros.board_record import BoardDescription
from ...ros.clock import ClockRecord
from ...topics import Topic, Update
from ..config import Config

#: a command for an actuator: the value (or an Update, or a list whose first item is the value)
CommandHandler = Callable[[Any], None]


class Claims(Protocol):
    """Names held daemon-wide (daemon/claims.py): a board's name and ``board.id``, its message
    type names, so two boards never merge or clash."""

    def name(
        self, owner: object, wanted: str, url: str, board_id: str | None = None
    ) -> tuple[str, str | None]:
        """(owner, wanted name, owner's URL, the board.id its board states or None for a name
        the config gives its URL) -> (granted name, warning or None)."""
        ...

    def type(self, board: str, t: Transducer) -> tuple[str, str | None]:
        """(board name, transducer) -> (message type name, warning or None)."""
        ...

    def claim_id(self, owner: object, board_id: str, url: str) -> str | None:
        """A warning when another connected board states ``board_id`` too."""
        ...

    def release_id(self, owner: object) -> None:
        """``owner``'s board is gone."""
        ...

    def id_conflict(self, owner: object) -> str | None:
        """The warning while another connected board states the owner's ``board.id``."""
        ...


class Faces(Protocol):
    """Every face of the daemon, as a session reaches them (daemon/fanout.py)."""

    def declare(self, topic: Topic) -> None:
        """A topic, to every face."""
        ...

    def publish(self, update: Update) -> None:
        """An update, to every face (the sample path; the board's reading thread)."""
        ...

    def add_command(self, name: str, topic: Topic, handler: CommandHandler) -> None:
        """An actuator's command topic, offered on every face (through the allow-list)."""
        ...

    def remove_command(self, name: str) -> None:
        """That command topic withdrawn (the board is gone)."""
        ...

    def record_clock(self, topic: str, record: ClockRecord) -> None:
        """One clock exchange of the board, for recordings (``ros/clock.py``)."""
        ...

    def offer_config(self, board: str, keys: list[ConfigKey], values: dict[str, Value]) -> None:
        """A board's run-time configuration, offered on every face (each changes it as
        itself, through the daemon)."""
        ...

    def config_changed(self, board: str, values: dict[str, Value]) -> None:
        """A board's configuration changed: the faces follow."""
        ...

    def describe_board(self, record: BoardDescription) -> None:
        """A board came up (validated, topics declared): its description, for recordings."""
        ...

    def log(self, line: LogLine) -> None:
        """A line of a board's log (``board_log.py``), to every face."""
        ...


@dataclass(frozen=True)
class SessionContext:
    config: Config  #: daemon-wide settings (backoff, diagnostics period, package, remap)
    reactor: Reactor | None  #: the loop that reads the boards (None: a reader thread each)
    typestore: Any  #: rosbags typestore of the configured distro (standard types)
    realtime_offset_ns: int  #: CLOCK_REALTIME - CLOCK_MONOTONIC at start (published host times)
    probe_gap: Callable[[], float]  #: s between a tracking board's clock probes (the budget)
    claims: Claims  #: names held daemon-wide
    faces: Faces  #: every face
    #: the daemon's one clock: what the supervisor reads the time from and sleeps on
    #: (liveness.py), the boards' links run on (their ``last_frame``), and every deadline
    clock: Clock = SYSTEM_CLOCK
