"""The daemon's fan-out: every topic, update, clock record, command topic and configuration a
board session makes goes to every publisher (the in-process bus, Zenoh, ROS, MCAP, ...).

A publisher that raises is counted (``errors``: the daemon's ``publish_errors``) and logged,
and never allowed to stop the sample path of any board: one face that cannot carry a topic or
an update must not cost the others theirs.  Command topics are offered on every face through
the allow-list (``commands.py``): a face that may not command a topic gets a handler that
refuses and counts.
"""

from __future__ import annotations

import logging
import time
from typing import Any

from ..host.config import ConfigKey, Value
from ..publishers.base import Publisher
from ..publishers.bus import Bus
from ..ros.board_record import BoardDescription
from ..ros.clock import ClockRecord
from ..topics import Topic, Update
from .commands import CommandGate
from .context import CommandHandler

log = logging.getLogger(__name__)


class Fanout:
    def __init__(self, publishers: list[Publisher], bus: Bus, gate: CommandGate) -> None:
        """``publishers``: the daemon's list (read at each call: it may still grow)."""
        self.publishers = publishers
        self.bus = bus
        self.gate = gate
        self.errors = 0  #: calls into a publisher that raised

    def declare(self, topic: Topic) -> None:
        for p in self.publishers:
            try:
                p.add_topic(topic)
            except Exception:  # one face that cannot carry a topic must not stop the board
                self.errors += 1
                log.exception("publisher %s cannot declare %s", p.name, topic.name)

    def publish(self, update: Update) -> None:
        for p in self.publishers:
            try:
                p.publish(update)
            except Exception:  # (as declare)
                self.errors += 1
                log.exception("publisher %s failed", p.name)

    def record_clock(self, topic: str, record: ClockRecord) -> None:
        for p in self.publishers:
            try:
                p.clock_record(topic, record)
            except Exception:  # (as publish)
                self.errors += 1
                log.exception("publisher %s failed on a clock record", p.name)

    def describe_board(self, record: BoardDescription) -> None:
        for p in self.publishers:
            try:
                p.board_description(record)
            except Exception:  # (as declare)
                self.errors += 1
                log.exception("publisher %s failed on %s's description", p.name, record.board)

    def add_command(self, name: str, topic: Topic, handler: CommandHandler) -> None:
        def sent(value: Any) -> None:  # (what the actuator refuses raises: not recorded)
            handler(value)
            now = time.time_ns()
            for p in self.publishers:
                try:
                    p.command_sent(name, topic, value, now)
                except Exception:  # (as declare)
                    self.errors += 1
                    log.exception("publisher %s failed on a command to %s", p.name, name)

        gate = self.gate  # (who may command what: commands.py)
        self.bus.add_command(name, gate.wrap("bus", True, name, sent))
        for p in self.publishers:
            try:
                p.add_command_topic(
                    name, topic, gate.wrap(p.name, bool(p.takes_commands), name, sent)
                )
            except Exception:  # (as declare)
                self.errors += 1
                log.exception("publisher %s cannot take commands on %s", p.name, name)

    def offer_config(
        self, board: str, keys: list[ConfigKey], values: dict[str, Value], apply: Any
    ) -> None:
        for p in self.publishers:
            try:
                p.add_config(board, keys, values, apply)
            except Exception:  # (as declare)
                self.errors += 1
                log.exception("publisher %s cannot offer %s's configuration", p.name, board)

    def config_changed(self, board: str, values: dict[str, Value]) -> None:
        for p in self.publishers:
            try:
                p.config_changed(board, values)
            except Exception:  # (as declare)
                self.errors += 1
                log.exception("publisher %s failed on %s's configuration", p.name, board)

    def diagnostics(self, status: list[dict[str, Any]], now_ns: int) -> None:
        for p in self.publishers:
            try:
                p.diagnostics(status, now_ns)
            except Exception:  # (as declare)
                log.exception("publisher %s failed on diagnostics", p.name)
