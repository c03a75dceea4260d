"""One board's run-time configuration in the daemon (docs/configuration.md).

Theory of operation
-------------------
The daemon's config file may give a board keys (``[boards.<name>.config]``): they are applied at
every connect and again after every reset of the board that the clock sync notices without the
link dropping (a board forgets what was set at run time when it restarts, unless it was saved).
Any face may change the configuration while the board runs (``Daemon.configure``, the control
endpoint behind ``missing-link config``, ROS 2 parameters): each change goes to the board all at
once or not at all (the board's ``a2jConfigSet``), then every face hears the new values
(``on_change``: ROS 2 parameters follow).  The last change (when, by whom, what) is in the
status and on ``/diagnostics``.

The keys of an actuator (its ``enabled``, ``failsafe_ms``, limits, centre, ...: every key of a
transducer the board describes as an actuator) are commands: a servo re-clamps the pulse it
holds to new limits, ``failsafe_ms = 0`` turns its failsafe off.  A face's change is handed
the daemon's ``guard`` (docs/security.md): before anything is sent, the values are read again
and the actuators whose keys the set, reset or save would change (a save: what the board boots
with) go to the guard, which refuses unless that face takes commands and the allow-list admits
the actuator's command topic.  The config file's keys (the operator's own) pass no guard.

A board without run-time configuration (the 2014 firmware) keeps working: keys given for it
are a warning, and ``configure`` says it is not configurable.  Keys from the file that the
board refuses are a warning too, with the board's reason: the board runs with what it has.
Calls are serialised (one change at a time per board); they block the caller, never the I/O
loop.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from ...errors import CallTimeout, ConfigError, MissingLinkError
from ...host.board import Board
from ...host.config import (
    ST_DIRTY,
    ST_LOADED,
    ST_SAVED,
    ConfigKey,
    NotConfigurable,
    Value,
    actuators_changed,
)

#: (the actuators a configuration change would change) -> None, or raises to refuse it
Guard = Callable[[list[str]], None]


@dataclass(frozen=True)
class RunConfigContext:
    """What a board's run-time configuration needs of its session and the daemon."""

    name: Callable[[], str]  #: the board's topic name now
    #: the board's keys from [boards.<name>.config] (asked at every connect: the name is the
    #: board's own until then)
    wanted: Callable[[], Mapping[str, Any]] = dict
    warn: Callable[[str], None] = lambda text: None
    #: (board name, keys, values, configure): every face offers the keys (ROS 2 parameters);
    #: the daemon hands each face its own way to change them, through its command gate
    on_keys: Callable[[str, list[ConfigKey], dict[str, Value], Any], None] = (
        lambda name, keys, values, apply: None
    )
    on_change: Callable[[str, dict[str, Value]], None] = lambda name, values: None


class RunConfig:
    def __init__(self, ctx: RunConfigContext) -> None:
        self.ctx = ctx
        self.board: Board | None = None
        self.keys: list[ConfigKey] = []
        self.values: dict[str, Value] = {}
        self.state = 0
        self.changed_at: float | None = None  #: time.time() of the last change
        self.changed_by = ""
        self.changes = 0
        self._lock = threading.Lock()

    @property
    def configurable(self) -> bool:
        b = self.board
        return b is not None and b.settings.available

    # ---- the session's events (its supervisor thread) -----------------------------------------
    def on_connect(self, board: Board) -> None:
        """A new link: read the keys, apply the config file's, offer them on every face."""
        self.board = board
        self.keys, self.values = [], {}
        if not board.settings.available:
            if self.ctx.wanted():
                self.ctx.warn(
                    "not configurable (no a2jConfig functions): the keys of "
                    f"[boards.{self.ctx.name()}.config] are ignored"
                )
            return
        with self._lock:
            self.keys = board.settings.keys()
            self.values = board.config()
            self.state = board.settings.state
        self._apply_file("connect")
        self.ctx.on_keys(self.ctx.name(), self.keys, dict(self.values), self.configure)

    def read_at_connect(self, board: Board, give_up: Callable[[], bool]) -> None:
        """``on_connect``, asked again while the board does not answer in time (a late reply
        to the read or to the file's keys: a busy board or host), until ``give_up()`` (a
        handshake's time).  A configuration that cannot be read then, or otherwise (a board
        answering garbage), is warned, and the board still publishes: an optional function
        that hangs must not cost the board its samples."""
        while True:
            try:
                self.on_connect(board)
                return
            except CallTimeout as e:
                if give_up():
                    self.ctx.warn(f"run-time configuration unread: no answer in time ({e})")
                    return
            except MissingLinkError as e:
                self.ctx.warn(f"run-time configuration unreadable: {e}")
                return

    def on_reset(self) -> None:
        """The board restarted under the same link: what the file says, again."""
        if self.configurable:
            self._apply_file("board reset")

    def _apply_file(self, why: str) -> None:
        wanted = self.ctx.wanted()
        if not wanted:
            return
        try:
            self.configure(wanted, by=f"config file ({why})")
        except (ConfigError, MissingLinkError) as e:
            if isinstance(e, CallTimeout) and why == "connect":
                raise  # (a late reply: read_at_connect asks again; the board may have them)
            self.ctx.warn(f"[boards.{self.ctx.name()}.config] not applied: {e}")

    # ---- changes (any thread but the I/O loop) ------------------------------------------------
    def configure(
        self,
        values: Mapping[str, object],
        save: bool = False,
        by: str = "api",
        guard: Guard | None = None,
    ) -> dict[str, Value]:
        """Set keys, all or none.  ``guard``: a face's (the daemon's: keys of an actuator are
        commands), handed the actuators the change would change and raising to refuse it;
        None only for the config file's keys (the operator's own)."""
        board = self._board()
        with self._lock:
            if guard is not None:
                self._guard(board, guard, values, save)
            try:
                self.values = board.configure(values, save)
            finally:
                self.state = board.settings.state
            self._changed(by, values)
        return dict(self.values)

    def reset(
        self, erase_saved: bool = False, by: str = "api", guard: Guard | None = None
    ) -> dict[str, Value]:
        board = self._board()
        with self._lock:
            if guard is not None:  # (an erase is a change too: issue 43.11)
                self._guard(board, guard, None, False, erase_saved)
            self.values = board.reset_config(erase_saved)
            self.state = board.settings.state
            self._changed(by, {"(defaults)": True})
        return dict(self.values)

    def _guard(
        self,
        board: Board,
        guard: Guard,
        wanted: Mapping[str, object] | None,
        save: bool,
        erase: bool = False,
    ) -> None:
        """Hand ``guard`` the actuators a change would change, compared with what the board
        has now (read again: a board that restarted has forgotten what was set); an erase of
        the saved configuration changes every actuator's (what it boots with)."""
        actuators = {t.name for t in board.transducers or () if t.is_actuator}
        if not actuators:
            return
        now = board.config()
        keys = board.settings.keys()
        changed = actuators_changed(keys, actuators, now, wanted, save, erase)
        if changed:
            guard(changed)

    def read(self) -> dict[str, Value]:
        board = self._board()
        with self._lock:
            self.values = board.config()
            self.state = board.settings.state
        return dict(self.values)

    def _board(self) -> Board:
        board = self.board
        if board is None or not board.alive:
            raise MissingLinkError(f"{self.ctx.name()}: not connected")
        if not board.settings.available:
            raise NotConfigurable(board.name, "not configurable (no a2jConfig functions)")
        return board

    def _changed(self, by: str, what: Mapping[str, object]) -> None:
        self.changes += 1
        self.changed_at = time.time()
        self.changed_by = f"{by}: " + ", ".join(f"{k}={v}" for k, v in what.items())
        self.ctx.on_change(self.ctx.name(), dict(self.values))

    # ---- status ----------------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        if not self.keys:
            return {"configurable": self.configurable}
        names = ((ST_SAVED, "saved"), (ST_LOADED, "loaded at boot"), (ST_DIRTY, "changed"))
        flags = [n for bit, n in names if self.state & bit]
        return {
            "configurable": True,
            "config": ", ".join(f"{k}={_text(v)}" for k, v in self.values.items()),
            "config_state": ", ".join(flags) or "defaults",
            "config_changes": self.changes,
            "config_changed": ""
            if self.changed_at is None
            else time.strftime("%Y-%m-%dT%H:%M:%S", time.localtime(self.changed_at)),
            "config_changed_by": self.changed_by,
        }


def _text(v: Value) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    return f"{v:g}" if isinstance(v, float) else str(v)


class Follows:
    """What follows the board's run-time configuration, at each connect (``on_keys``) and
    change (``on_change``): the sample path's host-time grid (``follow(values)``: True when the
    board became aligned just now, and then ``push_map()`` sends the clock map at once, not at
    the next exchange), the supervisor (``wake()``: a new ``failsafe_ms``, and the keepalive
    follows at once), and every face (``offer``, ``changed``: the session context's)."""

    def __init__(
        self,
        follow: Callable[[dict[str, Any]], bool],
        push_map: Callable[[], None],
        wake: Callable[[], None],
        offer: Callable[[str, list[ConfigKey], dict[str, Value]], None],
        changed: Callable[[str, dict[str, Value]], None],
    ) -> None:
        self._follow, self._push_map, self._wake = follow, push_map, wake
        self._offer, self._changed = offer, changed

    def on_keys(self, name: str, keys: list[Any], values: dict[str, Any], apply: Any) -> None:
        """(``apply``: the configuration's own, unguarded: the faces change it through the
        daemon instead, each as itself, where an actuator's keys are gated.)"""
        self._follow(values)
        self._offer(name, keys, values)

    def on_change(self, name: str, values: dict[str, Any]) -> None:
        if self._follow(values):
            self._push_map()
        self._wake()
        self._changed(name, values)
