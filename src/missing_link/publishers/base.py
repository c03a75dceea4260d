"""The publisher interface: what the daemon hands every face (topics, updates, command topics,
diagnostics).  ``publish`` runs on a board's reading thread: it must not block (queue work to a
thread of your own).  Publishers are found by name through :mod:`.registry`.

A face's life: made from its options (``make_publisher``: the registry hands it the
``[daemon]`` settings its entry declares), ``start(api)`` when the daemon starts (every face,
before any board: ``api`` is the daemon's public verbs a face may use, never the daemon), then
the calls below as boards come and go, and ``close()``.

Two numbers keep a face honest: ``dropped`` (messages the transport or a queue could not take:
a full queue, congestion, a write the library refused) and ``faults`` (exceptions: a bug, such
as an encoder that raises; counted by kind, the first of each logged with its traceback).  An
exception that escapes a call into a publisher is counted in its ``faults`` by the daemon's
fan-out; one caught on a publisher's own thread is counted there by the publisher.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from ..errors import MissingLinkError
from ..host.board_log import LogLine
from ..host.config import ConfigKey, Value
from ..logs import ErrorCounts
from ..ros.board_record import BoardDescription
from ..ros.clock import ClockRecord
from ..topics import Topic, Update

log = logging.getLogger(__name__)

#: (values) -> the configuration after it: a board's configuration changed by a face, all or
#: none (``Publisher.add_config``)
ApplyConfig = Callable[[dict[str, object]], dict[str, Value]]


@dataclass(frozen=True)
class DaemonApi:
    """What the daemon hands every face when it starts (``Publisher.start``): its public verbs,
    never the daemon itself."""

    status: Callable[[], list[dict[str, Any]]]  #: every board's status (``Daemon.status``)
    publisher_status: Callable[[], list[dict[str, Any]]]  #: every face's
    #: (board, values, save, by=, commands=) -> the configuration after it (Daemon.configure:
    #: an actuator's keys change only where the face takes commands)
    configure: Callable[..., dict[str, Value]]
    #: (board, erase_saved, by=, commands=) -> the configuration after it (Daemon.reset_config)
    reset_config: Callable[..., dict[str, Value]]
    declare: Callable[[Topic], None]  #: a topic of the face's own, to every face
    #: (command topic name, its topic, handler): a command topic of the face's own, offered on
    #: every face (through the allow-list)
    add_command: Callable[[str, Topic, Callable[[Any], None]], None]


class Publisher:
    name = "publisher"

    def start(self, api: DaemonApi) -> None:
        """The daemon starts (once, before any board): ``api`` for the face's life (a console
        that shows the status and changes a board's configuration keeps it).  Default: nothing."""

    def add_topic(self, topic: Topic) -> None:
        """A topic appeared (a board connected).  Called again after a reconnect."""

    def add_command_topic(self, name: str, topic: Topic, deliver: Callable[[Any], None]) -> None:
        """An actuator listens on ``name`` (messages of ``topic``'s type); publishers that reach
        other processes subscribe there and call ``deliver(values)``: a thesis-format message
        as a ``Command``, a standard type (``topic.standard``: ``std_msgs/msg/Float64``,
        ``sensor_msgs/msg/JointState``) as the decoded message.  Default: nothing."""

    def publish(self, update: Update) -> None:
        raise NotImplementedError

    def diagnostics(self, status: list[dict[str, Any]], now_ns: int) -> None:
        """Per-board status, about once a second (also published on /diagnostics)."""

    def add_config(
        self, board: str, keys: list[ConfigKey], values: dict[str, Value], apply: ApplyConfig
    ) -> None:
        """A board's run-time configuration (host/config.py), offered where a face has such a
        thing (ROS 2 parameters): ``apply(values)`` changes keys, all or none, raising
        ConfigError (the value) or MissingLinkError (the board) with the reason.  Default:
        nothing."""

    def config_changed(self, board: str, values: dict[str, Value]) -> None:
        """A board's configuration changed (through any face): follow it.  Default: nothing."""

    def clock_record(self, topic: str, record: ClockRecord) -> None:
        """One clock exchange of a board and the map after it (``ros/clock.py``), a few per
        second per board: recordings keep them on ``topic``.  Default: nothing."""

    def board_description(self, record: BoardDescription) -> None:
        """A board came up: its function table, properties and descriptors, and its topics
        (``ros/board_record.py``): recordings keep it for ``replay``.  Default: nothing."""

    def log(self, line: LogLine) -> None:
        """A line of a board's log (docs/board-log.md): ``/rosout`` on the ROS faces,
        ``/<board>/log`` in recordings.  Default: nothing."""

    def command_sent(self, name: str, topic: Topic, value: Any, now_ns: int) -> None:
        """A face handed the actuator on ``name`` (of ``topic``'s type) a command it took:
        ``value`` as the face gave it (a value, a list, an ``Update`` or a ``Command``), at host
        time ``now_ns`` (CLOCK_REALTIME).  Recordings keep it.  Default: nothing."""

    def close(self) -> None:
        """Flush and release everything.  Idempotent; must not block for long, whatever
        state the publisher is in."""

    #: whether commands from this face reach the boards (daemon/control/allowlist.py): True or False
    #: for
    #: the faces that carry commands (their ``commands`` option; by default True only where
    #: the face listens on loopback alone), None for those that carry none
    takes_commands: bool | None = None
    #: what turns this face's commands on (its key, an environment variable), said once with
    #: the first command refused on it (daemon/control/allowlist.py)
    commands_how: str = ""
    #: set when the publisher failed for good (e.g. a recording that cannot write): the daemon
    #: reports it as ERROR, and ``run`` exits non-zero
    error: str = ""
    #: messages this publisher had to drop (queue full, congestion, failed writes)
    dropped: int = 0

    @property
    def faults(self) -> ErrorCounts:
        """Exceptions in this face (a bug, not a drop), by kind; made on first use, so a
        publisher needs no ``__init__`` of the base."""
        faults: ErrorCounts | None = self.__dict__.get("_faults")
        if faults is None:  # (setdefault: two threads that race here get the same one)
            faults = self.__dict__.setdefault("_faults", ErrorCounts(log, f"publisher {self.name}"))
        return faults

    def status(self) -> dict[str, Any]:
        """One line of health for /diagnostics, ``Daemon.publisher_status()`` and summaries:
        ERROR when it failed for good, WARN when it caught errors (``errors``, ``error_kinds``)."""
        caught = self.faults.total
        return {
            "publisher": self.name,
            "level": 2 if self.error else 1 if caught else 0,
            "message": self.error or (f"{caught} errors caught (error_kinds)" if caught else "ok"),
            "error": self.error,
            "dropped": self.dropped,
            **self.faults.to_json(),
        }


class PublisherError(MissingLinkError):
    """A publisher cannot start (e.g. a recording directory that cannot be written)."""
