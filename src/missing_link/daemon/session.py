"""One board's session in the daemon: connect, validate, serve, notice loss, reconnect.

Theory of operation
-------------------
A supervisor thread runs the session through these states::

    connecting --handshake ok--> up --link lost or stale--> backoff --delay--> connecting
         \\--any failure (no board, bad or hostile board, bug)--> backoff
    any state --stop()--> stopped

A board is untrusted.  The supervisor catches *every* exception: the first time a given failure
happens its traceback is logged (a bug of ours shows once, not every backoff), ``error`` gets one
line, and the session backs off (``backoff_min`` doubling to ``backoff_max``) and tries again.
Nothing a board sends can end the thread.

``connecting`` opens the transport and owns the :class:`~missing_link.host.board.Board` *before* the
handshake, so ``stop()`` can close it at once.  The handshake has one overall deadline
(``handshake_timeout``) and small caps on the mapping, properties and descriptors (see
``client.handshake``).  Then everything the board said is validated, with errors that name the
board and the field: its name must give a topic token (``board-a`` -> ``board_a``, said in the
warnings) and must not be taken by another board (a second ``robot`` becomes ``robot_2``,
loudly); message type names are claimed daemon-wide, so two boards whose ``temp`` differ in data
type never share ``Temp`` (the second is qualified by its board: ``BoardBTemp``).

``up``: the board's reading thread (the daemon's I/O loop) decodes sample SIFs into ``Update``
objects (the sample path: ``SamplePath`` in ``sample_path.py``) and runs the clock probes on the
sync's schedule (``prober.py``); the supervisor runs actuator commands (latest wins) and watches
the link.  A link is *stale* when no intact frame arrived for ``link_timeout``: a frozen board, a
half-open TCP connection or a pulled cable looks like that.  Silence of half of that sends a
heartbeat (a clock probe at once, or ``a2jEcho``), so a quiet but healthy board always answers in
time; a stale link is closed, reported (state, error, ERROR in ``/diagnostics``) and reconnected.
Like a CANopen heartbeat consumer, the host decides from what it hears, not from what the
transport claims.

The session builds the clock sync (``_start_sync``: the board's ``ClockSync`` and its prober)
and, at each handshake, the topics; the sample path maps and publishes each sample with them.
Actuator commands arrive through :class:`~missing_link.daemon.actuators.Actuators`.

The session never holds the daemon: it is handed a :class:`SessionContext` of values and
callables (claims, declare, publish, command topics, the probe budget), and hands its own
children (sample path, prober, actuators) narrower ones still.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any

from ..descriptors import load_descriptor_file
from ..errors import BoardError, MissingLinkError
from ..host.board import Board
from ..ros.board_record import BoardDescription
from ..ros.clock import clock_topic
from ..ros.standard import StandardMapping, mapping_for
from ..timesync.sync import ClockSync
from ..topics import Topic
from ..transport import open_transport
from .actuators import Actuators
from .alignment import Alignment, grid_of
from .claims import board_token
from .config import BoardSpec
from .context import SessionContext
from .failsafe import FailsafeInfo, goodbye, keep_alive, keepalive_s
from .prober import ClockProber
from .sample_path import SamplePath
from .session_clock import ClockContext, SessionClock
from .settings import BoardSettings, SettingsContext

log = logging.getLogger(__name__)

CONNECTING, UP, BACKOFF, STOPPED = "connecting", "up", "backoff", "stopped"
#: diagnostic levels (diagnostic_msgs/DiagnosticStatus)
OK, WARN, ERROR = 0, 1, 2


class LinkStale(MissingLinkError):
    """No frame from the board for ``link_timeout``: frozen, unplugged or half-open."""


class BoardSession:
    def __init__(self, ctx: SessionContext, spec: BoardSpec) -> None:
        self.ctx = ctx
        self.spec = spec
        self.state = CONNECTING
        self.error = ""
        self.name = spec.name or spec.url
        self.board: Board | None = None
        self._said_goodbye: Board | None = None  # the board told the host is going
        # what happens to each sample (sample_path.py)
        self.path = SamplePath(ctx.publish, ctx.realtime_offset_ns)
        self.warnings: list[str] = []
        self.connects = 0
        self.failures = 0
        self.stale_links = 0
        self.rtt_us: float | None = None
        self.epoch = ""
        self.clock = SessionClock(
            ClockContext(
                url=spec.url,
                timeout=spec.timeout,
                link_timeout=spec.link_timeout,
                byte_ns=spec.byte_ns,
                realtime_offset_ns=ctx.realtime_offset_ns,
                probe_gap=ctx.probe_gap,
                record_clock=ctx.record_clock,
                on_error=self._probe_failed,
                on_rtt=self._set_rtt,
                wants_map=lambda: bool(self.path.grid),
            )
        )
        self._past: dict[str, int] = {}  # link counters of earlier connections (cumulative)
        self._logged: set[str] = set()  # failures whose traceback was logged once
        self._stop = threading.Event()
        self._wake = threading.Event()
        self.actuators = Actuators(self._wake.set, self._set_error)
        self.settings = BoardSettings(
            SettingsContext(
                name=lambda: self.name,
                wanted=lambda: ctx.config.board_config.get(self.name, {}),
                warn=self.warn,
                on_keys=self._offer_config,
                on_change=self._config_changed,
            )
        )
        self.alignment = Alignment()
        self.failsafe = FailsafeInfo()
        self._resets_seen = 0
        self._thread = threading.Thread(
            target=self._supervise, name=f"session:{spec.url}", daemon=True
        )

    @property
    def commands(self) -> int:
        """Actuator commands the board took (cumulative)."""
        return self.actuators.commands

    @property
    def command_errors(self) -> int:
        return self.actuators.command_errors

    @property
    def sync(self) -> ClockSync | None:
        return self.clock.sync

    @property
    def prober(self) -> ClockProber | None:
        return self.clock.prober

    @property
    def topics(self) -> dict[int, Topic]:
        """Transducer id -> topic, as of the latest handshake."""
        return self.path.topics

    def start(self) -> None:
        self._thread.start()

    def request_stop(self) -> None:
        """Begin stopping without waiting long (the daemon stops every session at once): the
        board hears goodbye first, so its actuators go safe now (failsafe.py)."""
        self._stop.set()
        self._wake.set()
        board = self.board
        if board is not None:
            if self.state == UP and board is not self._said_goodbye:
                self._said_goodbye = board  # (once: stop() asks again)
                goodbye(board)
            board.close()

    def stop(self, timeout: float = 1.0) -> None:
        self.request_stop()
        if self._thread.is_alive():
            self._thread.join(timeout)
        self.state = STOPPED

    # ---- supervisor thread -------------------------------------------------------------------
    def _supervise(self) -> None:
        delay = self.ctx.config.backoff_min
        while not self._stop.is_set():
            self.state = CONNECTING
            try:
                self._connect()
                delay = self.ctx.config.backoff_min
                self._serve()
            except Exception as e:  # noqa: BLE001 - nothing a board does may end this thread
                self._failed(e)
            finally:
                self._disconnect()
            if self._stop.is_set():
                break
            self.state = BACKOFF
            self._stop.wait(delay)
            delay = min(delay * 2, self.ctx.config.backoff_max)
        self.state = STOPPED

    def _failed(self, e: Exception) -> None:
        self.failures += 1
        if isinstance(e, MissingLinkError):
            text = str(e)
            line = text if text.startswith(self.spec.url) else f"{self.spec.url}: {text}"
            # the same failure again on every backoff (a board that is off) is said once; the
            # status and /diagnostics always carry it
            log.log(logging.DEBUG if text == self.error else logging.WARNING, "%s", line)
            self.error = text
            return
        # A bug (ours, or a board case nobody validated yet): the traceback once, then one line.
        self.error = f"internal error: {type(e).__name__}: {e}"
        key = f"{type(e).__name__}: {e}"
        if key in self._logged:
            log.warning("%s: %s (again)", self.spec.url, self.error)
        else:
            self._logged.add(key)
            log.exception("%s: session failed; retrying with backoff", self.spec.url)

    def _connect(self) -> None:
        spec = self.spec
        reactor = self.ctx.reactor
        board = Board(open_transport(spec.url), timeout=spec.timeout, reactor=reactor)
        board.batch_s = spec.batch_ms / 1000  # (when it reads on its own thread)
        self.board = board  # owned before the handshake: stop() closes it at once
        if self._stop.is_set():
            raise BoardError(spec.url, "stopping")
        board.handshake(
            describe=not spec.descriptors, deadline=time.monotonic() + spec.handshake_timeout
        )
        if spec.descriptors:
            transducers = load_descriptor_file(spec.descriptors)
        elif board.transducers is None:
            raise BoardError(
                board.name,
                "original board without descriptors; give them with "
                'descriptors = "FILE" in its [[board]] table',
            )
        else:
            transducers = board.transducers
        self.warnings = []
        self.name, taken = self.ctx.claim_name(self, self._board_name(board), spec.url)
        if taken:
            self.warn(taken)
        self.path.name = self.name
        cfg = self.ctx.config
        self.path.sync = None
        no_clock = self.clock.start(
            board, self.name, clock_topic(self.name, {t.name for t in transducers})
        )
        if no_clock:
            self.warn(no_clock)
        self.path.sync = self.clock.sync
        # New tables, filled as they are declared (a failure half-way leaves _disconnect the
        # command topics added so far to remove)
        topics: dict[int, Topic] = {}
        standard: dict[int, tuple[Topic, StandardMapping]] = {}
        self.path.topics, self.path.standard = topics, standard
        for t in transducers:
            topic_name = cfg.remap.get(f"/{self.name}/{t.name}", f"/{self.name}/{t.name}")
            type_name, clash = self.ctx.claim_type(self.name, t)
            if clash:
                self.warn(clash)
            topic = Topic.for_transducer(topic_name, self.name, t, cfg.package, type_name)
            topics[t.id] = topic
            self.ctx.declare(topic)
            try:
                mapping = mapping_for(t, self.name, self.ctx.typestore)
            except ValueError as e:
                self.warn(str(e))
                mapping = None
            if mapping is not None:
                std = Topic.standard_type(
                    f"{topic_name}/{mapping.suffix}",
                    self.name,
                    t,
                    mapping.type_name,
                    self.ctx.typestore,
                )
                standard[t.id] = (std, mapping)
                self.ctx.declare(std)
            if t.is_actuator:
                if t.call not in board.index:
                    raise BoardError(
                        self.name, f"actuator {t.name} names call={t.call}, which the board lacks"
                    )
                self.ctx.add_command(f"{topic_name}/cmd", topic, self.actuators.handler(t))
        self.ctx.describe_board(BoardDescription.of(self.name, spec.url, board.functions,
            board.properties, transducers, [topics[t.id].name for t in transducers]))  # fmt: skip
        epoch = board.properties.get("clock.epoch", "")
        self.path.resume(board, bool(epoch) and epoch == self.epoch, self._sif_count(board))
        self.epoch = epoch
        board.on_sif(None, self.path.on_sif)
        try:  # a board whose configuration cannot be read still publishes
            self.settings.on_connect(board)
        except MissingLinkError as e:
            self.warn(f"run-time configuration unreadable: {e}")
        self._resets_seen = self.sync.resets if self.sync is not None else 0
        self.connects += 1
        self.error = ""
        self.state = UP
        log.info("%s: up as %s with %d topics", self.spec.url, self.name, len(topics))

    def _board_name(self, board: Board) -> str:
        """The topic token this board publishes under (config name, else board.name)."""
        token, warning = board_token(self.spec.name, board.properties, board.url)
        if warning:
            self.warn(warning)
        return token

    def warn(self, text: str) -> None:
        if text not in self.warnings:
            self.warnings.append(text)
            log.warning("%s: %s", self.spec.url, text)

    def _serve(self) -> None:
        period = self.ctx.config.diagnostics_period
        link_timeout = self.spec.link_timeout
        next_ping = time.monotonic()
        next_beat = next_keep = 0.0
        board = self.board
        assert board is not None
        board.on_close(self._wake.set)  # a broken link wakes the supervisor at once
        while not self._stop.is_set() and board.alive:
            # Sleep until the next thing to do (commands and a dying link wake it early): an
            # idle board costs a wake-up a second; clock probes run on the reading thread.
            keep = keepalive_s(board, self.settings.values)  # (the board's failsafe)
            due = min(next_ping, max(board.last_frame + link_timeout / 2, next_beat))
            if keep is not None:
                due = min(due, next_keep)
            self._wake.wait(max(0.0, min(1.0, due - time.monotonic())))
            self._wake.clear()
            self.actuators.run(board, self._stop.is_set, self._push_map)
            sync = self.sync
            if sync is not None and sync.resets != self._resets_seen:
                self._resets_seen = sync.resets  # the board restarted: the file's keys again
                self.settings.on_reset()
            now = time.monotonic()
            silent = now - board.last_frame
            if silent > link_timeout:
                self.stale_links += 1
                raise LinkStale(
                    f"{self.name}: no frame from the board for {silent:.1f} s (frozen, "
                    "unplugged or a half-open link); reconnecting"
                )
            if keep is not None and now >= next_keep:
                next_keep = now + keep
                keep_alive(board)
            heartbeat = silent >= link_timeout / 2 and now >= next_beat
            if heartbeat:
                next_beat = now + link_timeout / 4
            ping = now >= next_ping
            if ping:
                next_ping = now + period
                if self.path.grid:  # the board's own account of its grid (alignment.py)
                    self.alignment.refresh(board)
                self.failsafe.refresh(board, self.settings.values)
            if self.prober is not None:
                if heartbeat:
                    self.prober.probe_now()  # answered (or timed out) on the reading thread
            elif ping or heartbeat:
                try:  # no clock exchanges to measure the round trip with
                    t0 = time.perf_counter()
                    board.call("a2jEcho", b"", timeout=min(self.spec.timeout, link_timeout / 3))
                    self.rtt_us = (time.perf_counter() - t0) * 1e6
                except MissingLinkError as e:
                    self.error = str(e)
        if not board.alive and not self._stop.is_set():
            self.error = f"link lost: {board.transport.url}"

    def _set_grid(self, values: dict[str, Any]) -> None:
        grid = grid_of(values, self.path.topics)
        if grid != self.path.grid:
            self.path.grid, self.path.grid_since_ns = grid, time.time_ns()

    def _offer_config(self, name: str, keys: list[Any], values: dict[str, Any], apply: Any) -> None:
        self._set_grid(values)
        self.ctx.offer_config(name, keys, values, apply)

    def _config_changed(self, name: str, values: dict[str, Any]) -> None:
        aligned_before = bool(self.path.grid)
        self._set_grid(values)
        if self.path.grid and not aligned_before:
            try:  # the grid needs the map now, not at the next exchange
                self._push_map()
            except MissingLinkError as e:
                self._set_error(str(e))
        self.ctx.config_changed(name, values)

    def _push_map(self) -> None:
        self.clock.push_map()

    def _set_error(self, text: str) -> None:
        self.error = text

    def _probe_failed(self, board: Board, text: str) -> None:
        if self.board is board:  # (a late reply of an earlier link says nothing now)
            self.error = text

    def _set_rtt(self, us: float) -> None:
        self.rtt_us = us

    def _disconnect(self) -> None:
        try:
            for topic in self.topics.values():
                self.ctx.remove_command(f"{topic.name}/cmd")
        finally:
            board, self.board = self.board, None
            if board is not None:
                board.close()
                for key, value in _link_counters(board).items():
                    self._past[key] = self._past.get(key, 0) + value

    # ---- the sample path (board reader thread) -----------------------------------------------
    def _sif_count(self, board: Board) -> int | None:
        if "a2jSifCount" not in board.index:
            return None
        try:
            payload = board.call_ok("a2jSifCount", timeout=self.spec.timeout)
        except MissingLinkError:
            return None
        return int.from_bytes(payload[:8], "little") if len(payload) >= 8 else None

    def level(self) -> tuple[int, str]:
        """Diagnostic level and message: ERROR when not up, WARN when up with warnings."""
        if self.state != UP:
            return ERROR, self.error or self.state
        if self.warnings:
            return WARN, "; ".join(self.warnings)
        return OK, "up"

    def status(self) -> dict[str, Any]:
        """Counters are cumulative over every connection of this session."""
        b = self.board
        link = _link_counters(b) if b is not None else {}
        level, message = self.level()
        return {
            "board": self.name,
            "url": self.spec.url,
            "state": self.state,
            "level": level,
            "message": message,
            "error": self.error,
            "serial": b.properties.get("board.serial", "") if b else "",
            "connects": self.connects,
            "failures": self.failures,
            "stale_links": self.stale_links,
            **{k: self._past.get(k, 0) + link.get(k, 0) for k in _LINK_COUNTERS},
            **self.path.counters(),
            "commands": self.commands,
            "command_errors": self.command_errors,
            "rtt_us": round(self.rtt_us) if self.rtt_us is not None else None,
            "warnings": "; ".join(self.warnings),
            "clock_epoch": self.epoch,
            "map_pushes": self.clock.map_pushes,
            **self.settings.status(),
            **self.alignment.status(self.path.grid, self.path.topics),
            **self.failsafe.info,
            **(self.sync.status() if self.sync is not None else {"sync_state": "none"}),
        }


_LINK_COUNTERS = (
    "frames",
    "bad_checksums",
    "bad_escapes",
    "cut_frames",
    "junk_bytes",
    "lost_sifs",
    "timeouts",
    "late_replies",
)


def _link_counters(board: Board) -> dict[str, int]:
    d, c = board.conn.decoder.stats, board.conn.stats
    return {
        "frames": d.frames,
        "bad_checksums": d.bad_checksums,
        "bad_escapes": d.bad_escapes,
        "cut_frames": d.cut_frames,
        "junk_bytes": d.junk_bytes,
        "lost_sifs": c.sifs_lost,
        "timeouts": c.timeouts,
        "late_replies": c.late_replies,
    }
