"""Firmware updates of the boards a daemon holds (``missing-link update NAME BOARDFILE``,
through the control endpoint: ops.py), so an update never fights the daemon for the
port, and the daemon's other boards go on publishing through it.

Theory of operation
-------------------
``update`` (a MicroPython board): the image comes as a file the client wrote in the endpoint's
own directory (over a request's size), read and packed again (``parse_image``, ``image_of``:
only an MLFW1 image gets through); host/update.py's :class:`~missing_link.host.update.Updater`
takes the session's board through the steps.  After the switch the board restarts and the
session reconnects by itself, as after any lost link; ``reconnect`` waits for the session to be
up on a new link, and that board is confirmed.  One update of a board at a time.

Each step is the session's ``update_status`` (``{state, done, total, from, to}``: the status key
``update`` of ``status()``, ``/diagnostics`` and the web console), the end a line of the board's
log (every face that shows logs) and of the daemon's own.

``release`` / ``retake`` (an AVR board, written by avrdude through its bootloader: deploy/update.py
runs avrdude): the session lets go of its port until ``retake`` or the time given is up
(hold.py), then connects again as after any lost link.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from ...errors import BoardError, ConfigError, MissingLinkError
from ...host.board import Board
from ...host.board_log import LogLine
from ...host.clock import SYSTEM_CLOCK, Clock
from ...host.update import (
    MAX_IMAGE,
    TRIAL_S,
    Image,
    Outcome,
    Target,
    Updater,
    UpdateRefused,
    image_of,
    parse_image,
)
from ..session.session import BoardSession
from ..session.status import SessionState

log = logging.getLogger(__name__)

Handler = Callable[[dict[str, Any]], dict[str, Any]]
#: what ``release`` may hold a port for (s)
MAX_RELEASE_S = 600.0
#: how long a session may take to let go of its port (a handshake under way ends first)
PARK_S = 15.0


class BoardUpdates:
    """The control endpoint's update ops over the daemon's sessions (``session(board)``)."""

    def __init__(
        self,
        session: Callable[[str], BoardSession],
        log_line: Callable[[LogLine], None],
        clock: Clock = SYSTEM_CLOCK,
        gate: Callable[[BoardSession, str], None] = lambda s, what: None,
    ) -> None:
        """``gate(session, what)``: the allow-list on an update or a release (either changes
        what every actuator of the board does: CommandRefused unless it admits them all)."""
        self.clock = clock  #: the daemon's: the update's deadlines
        self._session = session
        self._log_line = log_line
        self._gate = gate
        self._busy: set[str] = set()
        self._lock = threading.Lock()

    def handlers(self) -> dict[str, Handler]:
        return {"update": self.update, "update_status": self.status,
                "release": self.release, "retake": self.retake}  # fmt: skip

    def status(self, r: dict[str, Any]) -> dict[str, Any]:
        return {"update": self._session(str(r["board"])).update_status}

    def update(self, r: dict[str, Any]) -> dict[str, Any]:
        s = self._session(str(r["board"]))
        board = s.board
        if s.state != SessionState.UP or board is None:
            raise BoardError(s.name, f"not up ({s.state}): no update now")
        self._gate(s, "a firmware update")
        image = _image(r)
        target = Target.from_json(dict(r.get("target") or {}))
        trial_s = int(r.get("trial_s", TRIAL_S))
        old = board.properties.get("fw.hash", "")

        def report(state: str, done: int, total: int) -> None:
            s.update_status = {"state": state, "done": done, "total": total, "from": old,
                               "to": image.fw_hash}  # fmt: skip

        try:
            seen = [board]  # (each reconnect: a board on a link not seen before)
            with self._only_one(s):
                outcome = Updater(
                    image, target, trial_s=trial_s, report=report, clock=self.clock.monotonic
                ).run(board, lambda deadline: _back(s, seen, deadline, self.clock))
        except UpdateRefused as e:
            report("refused", 0, len(image.data))
            self._say(s, logging.WARNING, f"firmware update refused: {e}")
            return {"error": str(e), "kind": "refused"}
        except MissingLinkError as e:
            st = s.update_status or {}
            report("failed", int(st.get("done", 0)), len(image.data))
            self._say(s, logging.WARNING, f"firmware update failed: {e}")
            raise
        self._said(s, outcome)
        return {"outcome": outcome.to_json()}

    @contextmanager
    def _only_one(self, s: BoardSession) -> Iterator[None]:
        with self._lock:
            if s.name in self._busy:
                raise BoardError(s.name, "an update of this board is under way")
            self._busy.add(s.name)
        try:
            yield
        finally:
            with self._lock:
                self._busy.discard(s.name)

    def _said(self, s: BoardSession, o: Outcome) -> None:
        self._say(s, logging.INFO if o.ok else logging.WARNING, "firmware " + o.summary())

    def _say(self, s: BoardSession, level: int, text: str) -> None:
        log.log(level, "%s", text)
        try:
            self._log_line(LogLine(board=s.name, level=level, text=text, host_ns=time.time_ns()))
        except Exception as e:  # noqa: BLE001 - a face that fails counts it itself (fanout)
            log.debug("update log line: %s", e)

    def release(self, r: dict[str, Any]) -> dict[str, Any]:
        s = self._session(str(r["board"]))
        seconds = float(r.get("seconds", 180))
        if not 0 < seconds <= MAX_RELEASE_S:
            raise ConfigError(f"release: seconds {seconds:g}: expected 0..{MAX_RELEASE_S:g}")
        self._gate(s, "release of its port")
        s.hold.take(seconds)
        board = s.board
        if board is not None:
            board.close()  # (the supervisor sees the link end, and parks at the hold)
        if not s.hold.wait_parked(PARK_S):
            s.hold.release()
            raise BoardError(s.name, f"the session did not let go of its port in {PARK_S:g} s")
        s.update_status = {"state": "port let go", "done": 0, "total": 0}
        self._say(s, logging.INFO, f"port {s.spec.url} let go for a firmware update")
        return {"url": s.spec.url, "seconds": seconds}

    def retake(self, r: dict[str, Any]) -> dict[str, Any]:
        s = self._session(str(r["board"]))
        s.hold.release()
        s.update_status = {"state": "port taken back", "done": 0, "total": 0}
        return {"state": s.state}


def _image(r: dict[str, Any]) -> Image:
    """The image the client wrote, checked and packed again."""
    path = Path(str(r.get("image", "")))
    try:
        with path.open("rb") as f:
            blob = f.read(MAX_IMAGE + 1)
        files = parse_image(blob)
        return image_of(files, str(r.get("version", "")), str(r.get("key_file", "")))
    except OSError as e:
        raise ConfigError(f"update: cannot read the image {path}: {e.strerror or e}") from None
    except (ValueError, UnicodeDecodeError) as e:
        raise ConfigError(f"update: {path}: {e}") from None


def _back(s: BoardSession, seen: list[Board], deadline: float, clock: Clock) -> Board:
    """The session's board once it is up again on a link not in ``seen`` (added to it)."""
    never = threading.Event()
    while clock.monotonic() < deadline:
        b = s.board
        if s.state == SessionState.UP and b is not None and all(b is not x for x in seen):
            seen.append(b)
            return b
        if s.state is SessionState.STOPPED:
            break
        clock.wait(never, 0.05)
    raise BoardError(s.name, f"not up again ({s.state}: {s.error or 'no answer'})")
