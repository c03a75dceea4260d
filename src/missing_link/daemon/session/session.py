"""One board's session in the daemon: connect, validate, serve, notice loss, reconnect.

Theory of operation
-------------------
A supervisor thread runs the session through these states::

    connecting --handshake ok--> up --link lost or stale--> backoff --delay--> connecting
         \\--any failure (no board, bad or hostile board, bug)--> backoff
    any state --stop()--> stopped

A board is untrusted.  The supervisor catches *every* exception: ``error`` gets one line, and
the session backs off (``backoff_min`` doubling to ``backoff_max``) and tries again.  A
``MissingLinkError`` (the board, the link) is said once per new message; anything else is a bug
(ours, or a board case nobody validated yet), counted by kind in ``faults`` with whatever the
board's reading thread caught (SIF handlers, callbacks: ``Board(faults=...)``), its first of a
kind logged with the traceback; the status shows them (``errors``, ``error_kinds``).  Nothing a
board sends can end the thread.

``connecting`` opens the transport and owns the :class:`~missing_link.host.board.Board` *before* the
handshake, so ``stop()`` can close it at once (one that dials in is handed over by its
``board.id``, described: ``link.py``).  The handshake has one overall deadline
(``handshake_timeout``) and small caps on the mapping, properties and descriptors (see
``Board.handshake`` in ``host/board.py``).  Then everything the board said is validated, with
errors that name the board and the field: its name (the config's for its URL, else the
config's for its ``board.id``, else its ``board.name``) must give a topic token (``board-a`` ->
``board_a``, said in the warnings) and must not be taken by another board (a second ``robot``
becomes ``robot_2``, loudly); its ``board.id`` is claimed too (two connected boards that state
one id are both kept, both warned); message type names are claimed daemon-wide, so two boards
whose ``temp`` differ in data type never share ``Temp`` (the second is qualified by its board:
``BoardBTemp``).

``up``: the board's reading thread (the daemon's I/O loop) decodes sample SIFs into ``Update``
objects (the sample path: ``SamplePath`` in ``sample_path.py``) and runs the clock probes on the
sync's schedule (``prober.py``); the supervisor (``serve``) watches the link and starts what the
board is asked: actuator commands (latest wins: ``actuators.py``), the failsafe's keepalive, a
heartbeat, the board's own counts once a diagnostics period.  It never waits for any of them:
each is answered on the reading thread, one of a kind in flight (``inflight.py``), so a frozen
board, a queue of requests or a control call with a long timeout never holds it up.  A link is
*stale* when no intact frame arrived for ``link_timeout`` (``liveness.py`` decides, from
``last_frame`` alone): a frozen board, a half-open TCP connection or a pulled cable looks like
that.  Silence of half of that sends a heartbeat (a clock probe at once, or ``a2jEcho``), so a
quiet but healthy board always answers in time; a stale link is closed, reported (state, error,
ERROR in ``/diagnostics``) and reconnected.  Like a CANopen heartbeat consumer, the host decides
from what it hears, not from what the transport claims.  A board reset seen under the same link
re-applies the configuration file's keys on a thread of its own (they are calls to wait for).

``stop``: the board hears goodbye first (``a2jGoodbye``: its actuators safe at once); the
supervisor waits a bounded time for its answer, then closes the link.  From the goodbye on,
nothing of a command path reaches that board (``farewell.py``: actuator and timed commands,
``Daemon.call``, ``trigger_at``, ``configure`` are refused), though the session is still up.
The daemon asks every session at once, so the waits overlap.

At each handshake the session builds the clock sync (``clock.py``: the board's
``ClockSync`` and its prober) and the topics (``board_topics.py``); the sample path maps and
publishes each sample with them; actuator commands arrive through ``actuators.py``.

The session never holds the daemon: it is handed a :class:`SessionContext` of values and
callables (claims, declare, publish, command topics, the probe budget), and hands its own
children (sample path, prober, actuators) narrower ones still.
"""

from __future__ import annotations

import logging
import threading
from concurrent.futures import Future
from typing import Any

from ...errors import LinkLost, MissingLinkError
from ...host.board import Board
from ...host.link import CallResult
from ...host.results import LinkStats
from ...logs import ErrorCounts
from ...ros.board_record import BoardDescription
from ...ros.clock import clock_topic
from ...ros.standard import FrameIds
from ...timesync.sync import ClockSync
from ...topics import Topic
from ..claims import board_token
from ..config import BoardSpec
from .actuators import Actuators
from .background import Background
from .board_topics import BoardTopics, declare_topics, transducers_of
from .clock import ClockContext, SessionClock
from .context import SessionContext
from .failsafe import failsafe_ms, keepalive_s, wait_goodbye
from .farewell import Farewell
from .hold import PortHold
from .link import LinkSource, Mailbox, sif_count
from .liveness import LinkWatch
from .prober import ClockProber
from .reads import BoardReads
from .report import SessionReport
from .run_config import Follows, RunConfig, RunConfigContext
from .sample_path import SamplePath
from .status import Identity, Level, SessionState

log = logging.getLogger(__name__)

OK, WARN, ERROR = Level


class LinkStale(MissingLinkError):
    """No frame from the board for ``link_timeout``: frozen, unplugged or half-open."""


class BoardSession(SessionReport):
    def __init__(
        self, ctx: SessionContext, spec: BoardSpec, mailbox: Mailbox | None = None
    ) -> None:
        self.ctx = ctx
        self.spec = spec
        self.mailbox = mailbox  # (a board that dials in is handed over there: link.py)
        self.identity = Identity()  #: who the board is, as of the latest handshake
        self.state = SessionState.CONNECTING
        self.error = ""
        self.name = spec.name or spec.url
        self.board: Board | None = None
        #: the goodbye: once said, no call of a command path reaches that board (farewell.py)
        self.farewell = Farewell()
        #: its port let go for a while (an AVR update: control/updates.py)
        self.hold = PortHold(ctx.clock)
        #: the last firmware update's state (control/updates.py)
        self.update_status: dict[str, Any] | None = None
        self._serving = False  # serve() runs: late answers may still say something
        #: bugs caught by the supervisor and on the board's reading thread, by kind (cumulative)
        self.faults = ErrorCounts(log, spec.url)
        # what happens to each sample (sample_path.py; its bugs counted with the reading thread's)
        self.path = SamplePath(
            ctx.faces.publish, ctx.realtime_offset_ns, ctx.faces.log, self.faults
        )
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
                record_clock=ctx.faces.record_clock,
                on_error=self._probe_failed,
                on_rtt=lambda us: setattr(self, "rtt_us", us),
                wants_map=lambda: bool(self.path.grid),
            )
        )
        self.past_links = LinkStats()  #: link counters of its earlier links (cumulative)
        self._stop = threading.Event()
        self._wake = threading.Event()
        self.actuators = Actuators(
            self._wake.set, self._set_error, self.farewell.call_future, self._timed_within
        )
        self._actuator_calls: dict[str, str] = {}  # an actuator's function -> its command topic
        self._command_topics: list[str] = []  # every command topic offered (withdrawn at the end)
        self.frames = FrameIds()  #: its transducers' frame ids (a run-time change survives)
        self.follows = Follows(  # (the grid, the map, the supervisor and the faces)
            self.path.follow, self._push_map_now, self._wake.set, ctx.faces.offer_config,
            ctx.faces.config_changed,
        )  # fmt: skip
        self.run_config = RunConfig(
            RunConfigContext(
                name=lambda: self.name,
                wanted=lambda: ctx.config.board_config.get(self.name, {}),
                warn=self.warn,
                on_keys=self.follows.on_keys,
                on_change=self.follows.on_change,
            )
        )
        #: what the supervisor asks of the board and never waits for (reads.py)
        self.reads = BoardReads(
            lambda b: bool(failsafe_ms(b, self.run_config.values)),
            lambda us: setattr(self, "rtt_us", us),
            self._call_failed,
        )
        self._resets_seen = 0
        # the file's keys again after a reset: calls to wait for, so not on the supervisor
        self._reapply = Background(
            f"session:{spec.url}:config", self.run_config.on_reset, self.faults
        )
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

    def command_topic(self, function: str) -> str | None:
        """The command topic of the actuator whose function is ``function`` (None: it moves
        nothing here), as of the latest handshake: the allow-list's name for it."""
        return self._actuator_calls.get(function)

    def actuator_topics(self) -> list[str]:
        """The command topic of every actuator, as of the latest handshake (what the board
        drives, by the allow-list's names)."""
        return list(self._actuator_calls.values())

    def start(self) -> None:
        self._thread.start()

    def request_stop(self) -> None:
        """Begin stopping without waiting (the daemon stops every session at once): the board
        hears goodbye first, so its actuators go safe now (failsafe.py); the supervisor waits
        a bounded time for its answer, then closes the link."""
        self._stop.set()
        self._wake.set()
        if self.mailbox is not None:
            self.mailbox.close()  # (a board still waiting for this session: closed)
        board = self.board
        if board is None:
            return
        up = self.state == SessionState.UP
        answer = self.farewell.say(board) if up else None  # (once per link)
        if answer is None:
            board.close()  # nothing to wait for: a handshake under way ends at once

    def stop(self, timeout: float = 1.0) -> None:
        self.request_stop()
        if self._thread.is_alive():
            self._thread.join(timeout)
        board = self.board
        if board is not None and self._thread.is_alive():
            board.close()  # (a supervisor stuck in a system call: the link goes anyway)
        self.state = SessionState.STOPPED

    # ---- supervisor thread -------------------------------------------------------------------
    def _supervise(self) -> None:
        delay = self.ctx.config.backoff_min
        while not self._stop.is_set():
            self.hold.wait(self._stop)  # (its port let go: hold.py)
            self.state = SessionState.CONNECTING
            try:
                board = self._connect()
                delay = self.ctx.config.backoff_min
                self.serve(board)
            except Exception as e:  # noqa: BLE001 - nothing a board does may end this thread:
                self._failed(e)  # one line in error; a bug also counted by kind, said once
            finally:
                self._disconnect()
            if self._stop.is_set():
                break
            self.state = SessionState.BACKOFF
            self._stop.wait(delay)
            delay = min(delay * 2, self.ctx.config.backoff_max)
        self.state = SessionState.STOPPED

    def _failed(self, e: Exception) -> None:
        if isinstance(e, MissingLinkError):
            text = str(e)
            line = text if text.startswith(self.spec.url) else f"{self.spec.url}: {text}"
            # the same failure again on every backoff (a board that is off) is said once; the
            # status and /diagnostics always carry it
            log.log(logging.DEBUG if text == self.error else logging.WARNING, "%s", line)
            self.error = text
        else:  # A bug (ours, or a board case nobody validated yet): counted by kind, its
            # traceback logged the first time; the status carries the line
            self.error = f"internal error: {type(e).__name__}: {e}"
            self.faults.caught("session", e, "session (retrying with backoff)")
        self.failures += 1  # (after the error: who sees the count sees why)

    def _own(self, board: Board) -> None:
        self.board = board  # owned before the handshake: stop() closes it at once

    def _connect(self) -> Board:
        spec = self.spec
        board = LinkSource(spec, self.ctx.reactor, self.faults, self.mailbox, self.ctx.clock).open(
            self._stop, self._own
        )
        transducers = transducers_of(board.name, board.transducers, spec.descriptors or "")
        self.warnings = []
        self.identity = Identity.of(board.properties, board.url)
        twice = self.ctx.claims.claim_id(self, self.identity.board_id, spec.url)
        if twice:  # (shown while it lasts: level())
            log.warning("%s: %s", spec.url, twice)
        by_id = None if spec.name else self.identity.board_id  # (a configured name is its id's)
        self.name, taken = self.ctx.claims.name(self, self._board_name(board), spec.url, by_id)
        if taken:
            self.warn(taken)
        no_clock = self.clock.start(
            board, self.name, clock_topic(self.name, {t.name for t in transducers})
        )
        if no_clock:
            self.warn(no_clock)
        declared = BoardTopics()  # (filled as declared: _disconnect withdraws what there is)
        self.path.begin(self.name, self.clock.sync, declared)
        self._actuator_calls, self._command_topics = declared.calls, declared.commands
        declare_topics(
            self.ctx, self.name, board.index, transducers, self.actuators.handler, self.warn,
            declared, self.frames, lambda: self.run_config.values,
        )  # fmt: skip
        self.ctx.faces.describe_board(BoardDescription.of(self.name, spec.url, board.functions,
            board.properties, transducers,
            [declared.topics[t.id].name for t in transducers]))  # fmt: skip
        epoch = board.properties.get("clock.epoch", "")
        # (the path's boot, not self.epoch: a handshake that failed before its count leaves
        # the path's seq and count to the boot before, and this one must not take them on)
        same, self.epoch = bool(epoch) and epoch == self.path.boot, epoch
        self.path.listen(board, same)  # (before the count: no SIF falls between the two)
        board.on_sif(None, self.path.on_sif)
        self.path.resume(board, same, sif_count(board, spec.timeout))
        until = self.ctx.clock.monotonic() + spec.handshake_timeout  # (the handshake's time)
        self.run_config.read_at_connect(
            board, lambda: self._stop.is_set() or self.ctx.clock.monotonic() >= until
        )
        self._resets_seen = self.sync.resets if self.sync is not None else 0
        self.connects += 1
        self.error = ""
        self.state = SessionState.UP
        log.info("%s: up as %s with %d topics", self.spec.url, self.name, len(self.topics))
        return board

    def _board_name(self, board: Board) -> str:
        """The topic token this board publishes under: the config's name for its URL, else
        for its board.id ([boards.NAME] id), else its board.name."""
        named = self.spec.name or self.ctx.config.name_of_id(self.identity.board_id)
        token, warning = board_token(named, board.properties, board.url)
        if warning:
            self.warn(warning)
        return token

    def warn(self, text: str) -> None:
        if text not in self.warnings:
            self.warnings.append(text)
            log.warning("%s: %s", self.spec.url, text)

    def serve(self, board: Board) -> None:
        """Serve a connected board until its link is lost or stale, or the session stops (the
        supervisor's thread).  Nothing here waits for the board (liveness.py)."""
        clock = self.ctx.clock
        link_timeout = self.spec.link_timeout
        limit = min(self.spec.timeout, link_timeout / 3)  # what a call of ours may take
        watch = LinkWatch(link_timeout, self.ctx.config.diagnostics_period, clock.monotonic())
        board.on_close(self._wake.set)  # a broken link wakes the supervisor at once
        self.actuators.reset()
        self._serving = True
        try:
            while not self._stop.is_set() and board.alive:
                # Sleep until the next thing to do (commands and a dying link wake it early):
                # an idle board costs a wake-up a second; clock probes run on the reading thread.
                keep = keepalive_s(board, self.run_config.values)  # (the board's failsafe)
                clock.wait(self._wake, watch.wait_s(clock.monotonic(), board.last_frame, keep))
                self._wake.clear()
                if self._stop.is_set():
                    break
                self.actuators.run(board, self._stop.is_set, self.clock.push_map_future)
                self._notice_reset()
                turn = watch.turn(clock.monotonic(), board.last_frame, keep)
                if turn.host_late:  # (its silence is not the board's: asked again first)
                    log.warning("%s: the daemon ran %.2f s late", self.name, turn.host_late)
                if turn.stale:
                    self.stale_links += 1
                    raise LinkStale(
                        f"{self.name}: no frame from the board for {turn.silent:.1f} s (frozen, "
                        "unplugged or a half-open link); reconnecting"
                    )
                if turn.keepalive and keep is not None:
                    self.reads.keepalive.send(board, keep, limit)
                if turn.ping:
                    self.reads.counts(board, limit, bool(self.path.grid), self.path.log)
                if self.prober is not None:
                    if turn.heartbeat:
                        self.prober.probe_now()  # answered (or timed out) on the reading thread
                elif turn.ping or turn.heartbeat:  # no clock exchanges to time the round trip
                    self.reads.echo.start(board, b"", limit)
        finally:
            self._serving = False
        if not board.alive and not self._stop.is_set():
            self.error = f"link lost: {board.url}"

    def _notice_reset(self) -> None:
        """A board reset the clock sync noticed under the same link: the file's keys again,
        on a thread of their own (calls to wait for; the supervisor must not)."""
        sync = self.sync
        if sync is None or sync.resets == self._resets_seen:
            return
        self._resets_seen = sync.resets
        self._reapply.request()

    def _call_failed(self, e: MissingLinkError) -> None:
        if not isinstance(e, LinkLost):  # (a lost link: the session says why, e.g. stale)
            self._set_error(str(e))

    def _timed_within(self, tick: int) -> int | None:
        sync = self.clock.sync
        return sync.given_bound_ns(tick) if sync is not None else None

    def _push_map_now(self) -> None:
        try:
            fut = self.clock.push_map_future()
        except MissingLinkError as e:
            self._set_error(str(e))
            return
        if fut is not None:
            fut.add_done_callback(self._map_pushed)

    def _map_pushed(self, fut: Future[CallResult]) -> None:
        e = fut.exception()
        if isinstance(e, MissingLinkError):
            self._call_failed(e)

    def _set_error(self, text: str) -> None:
        if self._serving:  # (a call failing as the link closes must not hide why it did)
            self.error = text

    def _probe_failed(self, board: Board, text: str) -> None:
        if self.board is board:  # (a late reply of an earlier link says nothing now)
            self.error = text

    def _disconnect(self) -> None:
        try:
            for name in self._command_topics:
                self.ctx.faces.remove_command(name)
        finally:
            self.ctx.claims.release_id(self)
            board, self.board = self.board, None
            if board is not None:
                if self.farewell.said(board):  # (stopping: bounded, the actuators safe first)
                    wait_goodbye(self.farewell.answer)
                board.close()
                self.past_links += board.link_stats()
