"""What a board session may know of the daemon: plain values and callables, never the daemon.

A :class:`~missing_link.daemon.session.session.BoardSession` is handed one ``SessionContext`` (as
httpcore hands a connection a callback, never its pool).  Everything a session does to the rest
of the daemon goes through it: claiming its board name and its message type names (daemon-wide,
so two boards never merge or clash), declaring topics to every publisher, publishing updates,
offering and withdrawing actuator command topics.  Tests build one from lists and fakes
(``tests/test_daemon_parts.py``); the daemon builds one from itself
(:meth:`~missing_link.daemon.service.Daemon.session_context`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

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


@dataclass(frozen=True)
class SessionContext:
    config: Config  #: daemon-wide settings (backoff, diagnostics period, package, remap)
    reactor: Reactor | None  #: the loop that reads the boards (None: a reader thread each)
    typestore: Any  #: rosbags typestore of the configured distro (standard types)
    realtime_offset_ns: int  #: CLOCK_REALTIME - CLOCK_MONOTONIC at start (published host times)
    #: (owner, wanted name, owner's URL, the board.id its board states or None for a name the
    #: config gives its URL) -> (granted name, warning or None)
    claim_name: Callable[[object, str, str, str | None], tuple[str, str | None]]
    #: (board name, transducer) -> (message type name, warning or None)
    claim_type: Callable[[str, Transducer], tuple[str, str | None]]
    declare: Callable[[Topic], None]  #: a topic to every publisher
    publish: Callable[[Update], None]  #: an update to every publisher (the sample path)
    #: (command topic name, the actuator's topic, handler): offered on every face
    add_command: Callable[[str, Topic, CommandHandler], None]
    remove_command: Callable[[str], None]
    probe_gap: Callable[[], float]  #: s between a tracking board's clock probes (the budget)
    #: (topic, record): one clock exchange of the board, for recordings (``ros/clock.py``)
    record_clock: Callable[[str, ClockRecord], None] = lambda topic, record: None
    #: (board, keys, values, apply): a board's run-time configuration, offered on every face
    offer_config: Callable[[str, list[ConfigKey], dict[str, Value], Any], None] = (
        lambda board, keys, values, apply: None
    )
    #: (board, values): its configuration changed (the faces follow)
    config_changed: Callable[[str, dict[str, Value]], None] = lambda board, values: None
    #: the daemon's one clock: what the supervisor reads the time from and sleeps on
    #: (liveness.py), the boards' links run on (their ``last_frame``), and every deadline
    clock: Clock = SYSTEM_CLOCK
    #: a board came up (validated, topics declared): its description, for recordings
    describe_board: Callable[[BoardDescription], None] = lambda record: None
    #: (owner, board.id, owner's URL) -> a warning when another connected board states it too
    claim_id: Callable[[object, str, str], str | None] = lambda owner, board_id, url: None
    #: (owner): its board is gone
    release_id: Callable[[object], None] = lambda owner: None
    #: (owner) -> the warning while another connected board states its board.id, else None
    id_conflict: Callable[[object], str | None] = lambda owner: None
    #: a line of a board's log (``board_log.py``), to every publisher
    log: Callable[[LogLine], None] = lambda line: None
