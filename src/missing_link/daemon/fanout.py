"""The daemon's fan-out: every topic, update, clock record, command topic, configuration and
board log line a board session makes goes to every publisher (the in-process bus, Zenoh, ROS,
MCAP, ...).

A publisher that raises is counted in its own ``faults`` by kind (``ValueError in publish``:
its status and ``/diagnostics`` show them; the daemon's ``publish_errors`` is the sum here), its
first of a kind logged with the traceback, and never allowed to stop the sample path of any
board: one face that cannot carry a topic or an update must not cost the others theirs.  An
encoder that raises is such an error (a bug), not a drop.  Command topics are offered on every
face through the allow-list (``control/allowlist.py``): a face that may not command a topic gets a
handler that refuses and counts.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable
from typing import Any

from ..host.board_log import LogLine
from ..host.config import ConfigKey, Value
from ..publishers.base import Publisher
from ..publishers.bus import Bus
from ..ros.board_record import BoardDescription
from ..ros.clock import ClockRecord
from ..topics import Topic, Update
from .control.allowlist import CommandGate
from .session.context import CommandHandler


class Fanout:
    def __init__(
        self,
        publishers: list[Publisher],
        bus: Bus,
        gate: CommandGate,
        configure: Callable[..., dict[str, Value]],
    ) -> None:
        """``publishers``: the daemon's list (read at each call: it may still grow);
        ``configure(board, values, save, by=, commands=)``: a board's configuration changed by
        a face, gated (``Daemon.configure``)."""
        self.publishers = publishers
        self.bus = bus
        self.gate = gate
        self._configure = configure
        self.errors = 0  #: calls into a publisher that raised (each also in its ``faults``)

    def _failed(self, p: Publisher, where: str, e: Exception, what: str) -> None:
        self.errors += 1
        p.faults.caught(where, e, what)

    def _each(self, op: str, what: str, call: Callable[[Publisher], object]) -> None:
        """``call(p)`` for every publisher; what one raises is counted (``op``, ``what``): one
        face that cannot carry something must not stop a board or the other faces."""
        for p in self.publishers:
            try:
                call(p)
            except Exception as e:  # noqa: BLE001 - (counted by kind in the face's status)
                self._failed(p, op, e, what)

    def declare(self, topic: Topic) -> None:
        self._each("add_topic", f"declaring {topic.name}", lambda p: p.add_topic(topic))

    def publish(self, update: Update) -> None:
        for p in self.publishers:
            try:
                p.publish(update)
            except Exception as e:  # noqa: BLE001 - (as declare; an encoder's bug lands here)
                self._failed(p, "publish", e, f"publishing on {update.topic.name}")

    def record_clock(self, topic: str, record: ClockRecord) -> None:
        what = f"a clock record on {topic}"
        self._each("clock_record", what, lambda p: p.clock_record(topic, record))

    def describe_board(self, record: BoardDescription) -> None:
        what = f"{record.board}'s description"
        self._each("board_description", what, lambda p: p.board_description(record))

    def log(self, line: LogLine) -> None:
        self._each("log", f"{line.board}'s log", lambda p: p.log(line))

    def add_command(self, name: str, topic: Topic, handler: CommandHandler) -> None:
        def sent(value: Any) -> None:  # (what the actuator refuses raises: not recorded)
            handler(value)
            now = time.time_ns()
            what = f"recording a command to {name}"
            self._each("command_sent", what, lambda p: p.command_sent(name, topic, value, now))

        gate = self.gate  # (who may command what: control/allowlist.py)
        self.bus.add_command(name, gate.wrap("bus", True, name, sent))
        for p in self.publishers:
            try:
                on = bool(p.takes_commands)
                p.add_command_topic(name, topic, gate.wrap(p.name, on, name, sent, p.commands_how))
            except Exception as e:  # noqa: BLE001 - (as declare)
                self._failed(p, "add_command_topic", e, f"taking commands on {name}")

    def route(self, topic: str, value: Any) -> None:
        """``bus.send`` for a part of the daemon that routes commands on (joints.py): where
        ``[daemon] commands`` does not admit ``topic`` it raises (CommandRefused, counted under
        "bus" as the bus's own refusal is), so the router knows nothing was sent."""
        self.gate.check("bus", topic)
        self.bus.send(topic, value)

    def remove_command(self, name: str) -> None:
        self.bus.remove_command(name)

    def offer_config(self, board: str, keys: list[ConfigKey], values: dict[str, Value]) -> None:
        """Each face gets the board's ``configure`` as itself (its name, whether it takes
        commands: the keys of an actuator are commands, daemon/session/run_config.py)."""
        apply = functools.partial(self._configure, board)
        for p in self.publishers:
            try:
                mine = functools.partial(apply, by=p.name, commands=bool(p.takes_commands))
                p.add_config(board, keys, values, mine)
            except Exception as e:  # noqa: BLE001 - (as declare)
                self._failed(p, "add_config", e, f"offering {board}'s configuration")

    def config_changed(self, board: str, values: dict[str, Value]) -> None:
        what = f"following {board}'s configuration"
        self._each("config_changed", what, lambda p: p.config_changed(board, values))

    def diagnostics(self, status: list[dict[str, Any]], now_ns: int) -> None:
        # (the next round tries again)
        self._each(
            "diagnostics", "publishing /diagnostics", lambda p: p.diagnostics(status, now_ns)
        )
