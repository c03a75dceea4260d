"""The daemon's verbs on one board, by name or URL (the control endpoint, ROS 2 parameters, the
web console, applications): its session, a call through the allow-list, its run-time
configuration, a transducer's frame id, an actuator for the robot-level joints, a trigger at one
host time.  :class:`~missing_link.daemon.service.Daemon` has them; they need of it only its
sessions and its allow-list (``BoardApi``'s annotations)."""

from __future__ import annotations

import struct
from collections.abc import Iterable, Mapping
from typing import Any

from ..errors import BoardError, MissingLinkError
from ..host.board import Board
from ..host.config import Value
from ..host.link import CallResult
from .control.allowlist import BOARD_WIDE, CommandGate, called_function
from .control.config_guard import config_guard
from .control.endpoint import call_timeout
from .session.session import BoardSession
from .session.status import SessionState


class BoardApi:
    """One board's verbs, over the sessions of the daemon that has them."""

    sessions: list[BoardSession]  #: every board's session (replaced, never changed in place)
    commands: CommandGate  #: who may move what (``[daemon] commands``)

    def trigger_at(
        self, host_ns: int, boards: Iterable[str] | None = None, function: str = "setTriggerAt"
    ) -> dict[str, int]:
        """Have boards act at one host time (CLOCK_REALTIME ns), each at its own tick.

        Each board is first handed the current clock map (``a2jHostMap``); ``function`` (i64
        host ns) converts it on the board.  Returns board name -> the board tick it chose."""
        wanted = set(boards) if boards is not None else None
        ticks: dict[str, int] = {}
        for s in self.sessions:
            b, prober = s.board, s.prober
            if wanted is not None and s.name not in wanted:
                continue
            if s.state != SessionState.UP or b is None or prober is None or s.farewell.said(b):
                raise MissingLinkError(f"{s.name}: not up with a clock map; cannot trigger")
            self._gate(s, b, function, b"", "api")
            prober.push_map()
            reply = s.farewell.call_ok(b, function, struct.pack("<q", host_ns))
            ticks[s.name] = struct.unpack("<Q", reply[:8])[0] if len(reply) >= 8 else -1
        return ticks

    def session(self, board: str) -> BoardSession:
        """The session of the board named ``board`` (its topic name) or at URL ``board``."""
        sessions = self.sessions
        for s in sessions:
            if board in (s.name, s.spec.url):
                return s
        for s in sessions:  # the same device with other options (?baud=...)
            if "://" in board and board.split("?")[0] == s.spec.url.split("?")[0]:
                return s
        known = ", ".join(f"{s.name} ({s.spec.url})" for s in sessions) or "none"
        raise BoardError(board, f"no such board in this daemon (boards: {known})")

    def _up(self, board: str) -> tuple[BoardSession, Board]:
        s = self.session(board)
        b = s.board
        if s.state != SessionState.UP or b is None:
            raise BoardError(s.name, f"not up ({s.state}{': ' + s.error if s.error else ''})")
        if s.farewell.said(b):  # (the daemon stops: nothing more reaches it; farewell.py)
            raise BoardError(s.name, "told goodbye: the daemon stops")
        return s, b

    def call(
        self,
        board: str,
        function: str,
        payload: bytes = b"",
        timeout: float | None = None,
        *,
        by: str = "api",
    ) -> CallResult:
        """Call a function of a board this daemon holds (by name or URL), through its link.
        ``timeout``: s, finite and > 0, at most ``MAX_CALL_TIMEOUT`` (60: more is clamped);
        CommandRefused for an actuator's function (or an ``a2jAt`` of one) that ``[daemon]
        commands`` does not list, counted under ``by``."""
        t = call_timeout(timeout)
        s, b = self._up(board)
        self._gate(s, b, function, payload, by)
        return s.farewell.call(b, function, payload, t)

    def _gate(self, s: BoardSession, b: Board, function: str, payload: bytes, by: str) -> None:
        """The allow-list on a plain call: what the call would move is named by its topic; a
        configuration or firmware function, by every actuator the board has."""
        called = called_function(function, payload, b.functions)
        topic = s.command_topic(called)
        if topic is not None:
            self.commands.check(by, topic)
        elif called in BOARD_WIDE:
            self.commands.check_all(by, s.actuator_topics(), f"{s.name}: {called}")

    def gate_board(self, s: BoardSession, what: str, by: str = "control") -> None:
        """The allow-list on an op that changes what every actuator of a board does or lets go
        of its port (the control endpoint's ``update`` and ``release``)."""
        self.commands.check_all(by, s.actuator_topics(), f"{s.name}: {what}")

    def set_frame_id(self, board: str, transducer: str, frame_id: str) -> None:
        """The ``frame_id`` of a transducer's standard messages from now on (ValueError for a
        bad one, KeyError for a transducer the board has not described); every face follows
        (the ``ros2`` face's parameter ``<board>.<transducer>.frame_id`` too)."""
        frame = self.session(board).frames.get(transducer)
        if frame is None:
            raise KeyError(f"{board} has no transducer {transducer!r} with standard types")
        frame.set(frame_id)

    def _actuator(self, board: str, name: str) -> tuple[Any, Mapping[str, Value]] | None:
        """An actuator of a board that is up, and its board's configuration (joints.py)."""
        for s in self.sessions:
            if s.name == board and s.state == SessionState.UP:
                for topic in s.topics.values():
                    if topic.transducer.name == name and topic.transducer.is_actuator:
                        return topic.transducer, s.run_config.values
        return None

    def board_config(self, board: str) -> dict[str, Value]:
        """The board's run-time configuration now (``<transducer>.<key>`` -> value)."""
        return self._up(board)[0].run_config.read()

    def configure(
        self, board: str, values: Mapping[str, object], save: bool = False, **face: Any
    ) -> dict[str, Value]:
        """Set keys of a board's run-time configuration, all or none (``save``: keep them on
        the board); every face hears the new values.  Returns the configuration after it.
        ``face``: ``by`` (its name, "api") and ``commands`` (its option, True): the keys of an
        actuator are commands, refused and counted as one (control/config_guard.py)."""
        s = self._up(board)[0]
        by, on = str(face.get("by", "api")), bool(face.get("commands", True))
        return s.run_config.configure(values, save, by, config_guard(self.commands, s, by, on))

    def reset_config(self, board: str, erase_saved: bool = False, **face: Any) -> dict[str, Value]:
        """The board's defaults again (``erase_saved``: its saved configuration too); gated as
        ``configure`` where it changes an actuator's keys."""
        s = self._up(board)[0]
        by, on = str(face.get("by", "api")), bool(face.get("commands", True))
        return s.run_config.reset(erase_saved, by, config_guard(self.commands, s, by, on))
