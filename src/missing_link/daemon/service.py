"""The missing-link daemon: boards in, typed topics out.

Theory of operation
-------------------
The daemon owns the publishers and one :class:`~missing_link.daemon.session.session.BoardSession`
per configured board; the session module says how a board is connected, validated, served and
reconnected, and how its host times are made.  A session is handed a
:class:`~missing_link.daemon.session.context.SessionContext` (``session_context()``: values and
callables), never the daemon.  The daemon's own job is the fan-out and what sessions must agree
on:

* every ``Update`` a session makes goes to every publisher (``fanout.py``); a publisher that
  raises is counted by kind in its status (``errors``, ``error_kinds``; ``publish_errors`` sums
  them) and logged once per kind, never allowed to stop the sample path of any board;
* names are claimed daemon-wide (``claims.py``): a board name is held by one session (a second
  board that calls itself ``robot`` publishes as ``robot_2``, with a warning), and a message type
  name by one definition (a second board whose ``temp`` differs gets ``<Board>Temp``), so no
  recording ever holds two layouts under one type name;
* ``/diagnostics`` goes out every ``diagnostics_period`` with each session's status, level and
  counters;
* one I/O loop (``host/reactor.py``) reads every board on a descriptor, rather than a reader thread
  per board; each session keeps its own supervisor thread (handshake, probes, commands);
* boards can come and go while it runs: ``add_board`` / ``remove_board``, used by discovery
  (``discovery.py``: serial ports appearing and vanishing) and by boards that dial in
  (``dialin.py``: ``run --listen``, each board known by its ``board.id``); the session list is
  replaced, never changed in place, so readers iterate a consistent list without a lock;
* ``stop()`` asks every session to stop at once and returns within about a second whatever the
  boards do (a session stuck in a system call is left to its daemon thread).

Sessions share nothing but the publishers and these claims: one broken board never stops
another.
"""

from __future__ import annotations

import functools
import logging
import struct
import threading
import time
from collections.abc import Iterable, Mapping
from concurrent.futures import Future
from typing import Any

from ..descriptors import load_descriptor_file
from ..errors import BadURL, BoardError, MissingLinkError, without_prefix
from ..host.board import Board
from ..host.config import Value
from ..host.link import CallResult
from ..host.reactor import Reactor
from ..logs import ErrorCounts
from ..publishers.base import Publisher, PublisherError
from ..publishers.bus import Bus, Callback, LogCallback, Subscription
from ..publishers.registry import make_publisher
from ..ros.msgs import typestore_for
from ..topics import Command
from ..transport import check_url
from .claims import Claims
from .config import BoardSpec, Config
from .control.allowlist import CommandGate, called_function
from .control.config_guard import config_guard
from .control.endpoint import ControlServer, call_timeout
from .control.ops import control_handlers
from .fanout import Fanout
from .health import publisher_rows
from .intake.dialin import DialIns
from .intake.discovery import DiscoveryService, Enumerator, all_ports
from .joints import Joints
from .session.context import SessionContext
from .session.link import Mailbox
from .session.session import UP, BoardSession
from .session.status import SessionStatus

log = logging.getLogger(__name__)

__all__ = ["BoardSession", "Daemon", "connect"]


class Daemon:
    """Connects every configured board and publishes its transducers.  Use as a context manager."""

    def __init__(
        self,
        config: Config,
        extra_publishers: Iterable[Publisher] = (),
        enumerate_ports: Enumerator | None = None,
    ) -> None:
        self.config = config
        self._started = self._stopped = False
        for spec in config.boards:  # what retrying cannot fix fails here, before any thread
            check_url(spec.url)
            if spec.descriptors:
                load_descriptor_file(spec.descriptors)
        self.bus = Bus()
        self.commands = CommandGate(config.commands)
        self.publishers: list[Publisher] = [self.bus]
        listen = config.listen_spec()  # (BadURL, ValueError: before anything starts)
        self.dialins: DialIns | None = None  #: boards that dial in (run --listen)
        try:
            for name in config.publishers:
                if name != "bus":
                    try:
                        self.publishers.append(make_publisher(name, self._options(name)))
                    except MissingLinkError:  # (ConfigError too) already says what is wrong
                        raise
                    except Exception as e:  # zenoh.ZError, a taken port, ...: raised, one line
                        raise PublisherError(f"publisher {name} cannot start: {e}") from e
            if listen is not None:  # (bound here: a taken address fails the daemon at once)
                self.dialins = DialIns(config, listen, self.add_board)
        except BaseException:  # (broad, raised again: whatever stops the start, none is left)
            for p in self.publishers:  # a publisher that cannot start fails the daemon at once
                p.close()
            raise
        self.publishers.extend(extra_publishers)
        # one I/O loop reads every board on a descriptor (see reactor.py); it gathers streaming
        # SIFs for the smallest batch_ms any board asks for
        batch_ms = min((b.batch_ms for b in config.boards), default=BoardSpec.batch_ms)
        self.reactor = Reactor(batch_s=batch_ms / 1000)
        self.realtime_offset_ns = time.time_ns() - time.monotonic_ns()
        self.typestore = typestore_for(config.distro)
        self.claims = Claims(config.package)
        self.fanout = Fanout(self.publishers, self.bus, self.commands)  # (fanout.py)
        self.joints: Joints | None = None  #: the robot-level JointState ([joints]; joints.py)
        if config.joints is not None and config.joints.joints:
            self.joints = Joints(config.joints, config.remap, self.typestore, self.fanout.publish,
                                 self.fanout.route, self._actuator)  # fmt: skip
            self.publishers.append(self.joints)
        self._context = self.session_context()
        self.sessions = [BoardSession(self._context, spec) for spec in config.boards]
        self._stop = threading.Event()
        self._diag_thread = threading.Thread(
            target=self._diagnostics, name="diagnostics", daemon=True
        )
        self._sessions_lock = threading.Lock()  # add/remove replace the list (copy on write)
        self.discovery: DiscoveryService | None = None
        self.control: ControlServer | None = None  #: the local control endpoint, when on
        if config.discover is not None:
            ports = enumerate_ports or all_ports
            self.discovery = DiscoveryService(
                config.discover, ports, self.add_board, self.remove_board
            )

    @property
    def publish_errors(self) -> int:
        """Calls into a publisher that raised (the fan-out's count; each publisher's status
        has its own by kind)."""
        return self.fanout.errors

    def _options(self, name: str) -> dict[str, Any]:
        opts = dict(self.config.publisher_options.get(name, {}))
        opts.setdefault("distro", self.config.distro)
        if name in ("zenoh", "ros1", "ros2"):
            opts.setdefault("node", self.config.node)
        return opts

    def start(self) -> Daemon:
        """Start every session (idempotent: ``with connect(...)`` starts nothing twice)."""
        if self._started:
            return self
        self._started = True
        if self.joints is not None:
            self.joints.start(self.fanout.declare, self.fanout.add_command)
        self.reactor.start()
        for s in self.sessions:
            s.start()
        self._diag_thread.start()
        if self.discovery is not None:
            self.discovery.start()
        if self.dialins is not None:
            self.dialins.start(self.reactor)
        if self.config.control:
            try:
                verbs = (self.session, self._up, self.call, self.configure, self.reset_config)
                handlers = control_handlers(*verbs, self.fanout.log)
                self.control = ControlServer(self.config.control, handlers)
            except MissingLinkError as e:  # another daemon has it: this one runs without
                log.warning("%s; missing-link config/call/info reach this daemon's boards "
                            "only by another endpoint ([daemon] control)", e)  # fmt: skip
        return self

    @property
    def probe_gap(self) -> float:
        """s between one board's clock probes while tracking, so that all boards together
        stay within ``probe_budget`` exchanges per second."""
        return len(self.sessions) / self.config.probe_budget

    def add_board(self, spec: BoardSpec, mailbox: Mailbox | None = None) -> BoardSession:
        """Start a session for one more board (discovery, hotplug; one that dialed in, handed
        over in ``mailbox``); the others are untouched."""
        if mailbox is None:
            check_url(spec.url)
        session = BoardSession(self._context, spec, mailbox)
        with self._sessions_lock:
            if self._stopped:
                raise MissingLinkError("the daemon is stopped")
            self.sessions = [*self.sessions, session]
        session.start()
        return session

    def remove_board(self, url: str, timeout: float = 1.0) -> bool:
        """End the session of the board at ``url`` (its device vanished) and free its name."""
        with self._sessions_lock:
            gone = [s for s in self.sessions if s.spec.url == url]
            self.sessions = [s for s in self.sessions if s.spec.url != url]
        for s in gone:
            s.request_stop()
            s.stop(timeout)
            self.claims.release(s)
        return bool(gone)

    def close(self) -> None:
        """Stop every board session and close every publisher (the same as ``stop()``)."""
        self.stop()

    def stop(self) -> None:
        if self._stopped:
            return
        with self._sessions_lock:
            self._stopped = True
        self._stop.set()
        if self.discovery is not None:
            self.discovery.stop()
        if self.dialins is not None:
            self.dialins.stop()
        for s in self.sessions:
            s.request_stop()  # all at once: a stuck board costs its own time, not the others'
        deadline = time.monotonic() + 1.0
        for s in self.sessions:
            s.stop(max(0.0, deadline - time.monotonic()))
        if self._diag_thread.is_alive():
            self._diag_thread.join(max(0.05, deadline - time.monotonic()))
        self.reactor.stop(max(0.05, deadline - time.monotonic()))
        if self.control is not None:
            self.control.close()
        for p in self.publishers:
            try:
                p.close()
            except Exception as e:  # noqa: BLE001 - one face that fails to close must not keep
                p.faults.caught("close", e)  # the others open: counted, its traceback said

    def __enter__(self) -> Daemon:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ---- for applications (the thesis's Listing 8.4) -----------------------------------------
    def subscribe(
        self, topic: str, callback: Callback, *, queue: int = 10_000, latest: bool = False
    ) -> Subscription:
        """``callback(update)`` for every update on ``topic`` (patterns: ``*``, ``**``), on a
        thread of its own behind a bounded queue (``queue=0``: inline in the I/O loop that
        reads the boards); ``latest=True`` first hands over the newest update the topic
        already had (an actuator's state: the board reports it only when it changes).

        A topic may be subscribed before its board is up; once every board is up, a name that
        none of them has is a ``KeyError`` listing the topics there are (a typo, not a wait)."""
        pattern = "*" in topic or "?" in topic
        if not pattern and topic not in self.bus.topics and self._all_boards_known():
            known = ", ".join(sorted(self.bus.topics)) or "none"
            raise KeyError(
                f"no topic {topic!r}: every board is up and none has it (topics: {known})"
            )
        return self.bus.subscribe(topic, callback, queue=queue, latest=latest)

    def subscribe_logs(
        self, callback: LogCallback, board: str = "*", *, queue: int = 10_000
    ) -> Subscription:
        """``callback(line)`` for every line of the logs of ``board`` (a name or a pattern),
        typed (``host/board_log.py``), as ``subscribe`` delivers (docs/board-log.md)."""
        return self.bus.subscribe_logs(callback, board, queue=queue)

    def _all_boards_known(self) -> bool:
        """Every board there will be is up (no discovery adding more): a topic that none has
        now will not appear."""
        sessions = self.sessions
        return self.discovery is None and bool(sessions) and all(s.state == UP for s in sessions)

    def send(
        self, topic: str, value: Any, at_ns: int | None = None, timeout: float = 5.0
    ) -> int | None:
        """Command an actuator (``/<board>/<name>/cmd``).  Now: asynchronously, the latest
        command wins.  With ``at_ns`` (a host time, CLOCK_REALTIME ns): the board acts at that
        time (board/timing.py); this waits for the board's answer and returns the board tick
        it will act at, or raises the board's refusal (past, beyond what its clock map vouches
        for, no map yet).  CommandRefused when ``[daemon] commands`` does not list it."""
        self.commands.check("bus", topic)
        if at_ns is None:
            self.bus.send(topic, value)
            return None
        done: Future[int] = Future()
        self.bus.send(topic, Command([value], at_ns, done))
        return done.result(timeout)

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
            if s.state != UP or b is None or prober is None or s.farewell.said(b):
                raise MissingLinkError(f"{s.name}: not up with a clock map; cannot trigger")
            self._gate(s, b, function, b"", "api")
            prober.push_map()
            reply = s.farewell.call_ok(b, function, struct.pack("<q", host_ns))
            ticks[s.name] = struct.unpack("<Q", reply[:8])[0] if len(reply) >= 8 else -1
        return ticks

    # ---- one board, by name or URL (the control endpoint, ROS 2 parameters, applications) ------
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
        if s.state != UP or b is None:
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
        """The allow-list on a plain call: what the call would move is named by its topic."""
        topic = s.command_topic(called_function(function, payload, b.functions))
        if topic is not None:
            self.commands.check(by, topic)

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
            if s.name == board and s.state == UP:
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

    def wait_until_up(self, timeout: float = 10.0) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if all(s.state == UP for s in self.sessions):
                return True
            time.sleep(0.02)
        return False

    def status(self) -> list[dict[str, Any]]:
        """Per board: state, level, error and every counter (cumulative over reconnects), as
        plain dicts (JSON); ``snapshots()`` gives the same typed."""
        return [s.status() for s in self.sessions]

    def snapshots(self) -> list[SessionStatus]:
        return [s.snapshot() for s in self.sessions]

    def publisher_status(self) -> list[dict[str, Any]]:
        """Per publisher: level, error, dropped and what it has to say (queue, messages); then
        the control endpoint, the listener, the daemon's own threads (health.py)."""
        extra = [self.dialins.status()] if self.dialins is not None else []
        return publisher_rows(self.publishers, self.commands, self.control, self._own_faults(),
                              extra)  # fmt: skip

    def _own_faults(self) -> list[tuple[str, ErrorCounts]]:
        """What the daemon's own threads caught: the I/O loop's, discovery's."""
        own = [("reactor", self.reactor.faults)]
        if self.discovery is not None:
            own.append(("discovery", self.discovery.faults))
        return own

    def failures(self) -> list[str]:
        """One line per publisher that failed for good (a recording that stopped writing)."""
        return [f"{p.name}: {p.error}" for p in self.publishers if p.error]

    # ---- what sessions are handed ------------------------------------------------------------
    def session_context(self) -> SessionContext:
        """The values and callables a board session gets instead of the daemon."""
        return SessionContext(
            config=self.config,
            reactor=self.reactor,
            typestore=self.typestore,
            realtime_offset_ns=self.realtime_offset_ns,
            claim_name=self.claims.name,
            claim_type=self.claims.type,
            declare=self.fanout.declare,
            publish=self.fanout.publish,
            add_command=self.fanout.add_command,
            remove_command=self.bus.remove_command,
            probe_gap=lambda: self.probe_gap,
            record_clock=self.fanout.record_clock,
            offer_config=lambda b, keys, values, _c: self.fanout.offer_config(
                b, keys, values, functools.partial(self.configure, b)
            ),  # (each face changes them as itself: fanout.py)
            config_changed=self.fanout.config_changed,
            describe_board=self.fanout.describe_board,
            claim_id=self.claims.claim_id,
            release_id=self.claims.release_id,
            id_conflict=self.claims.id_conflict,
            log=self.fanout.log,
        )

    def _diagnostics(self) -> None:
        while not self._stop.wait(self.config.diagnostics_period):
            self.fanout.diagnostics(self.status() + self.publisher_status(), time.time_ns())


def connect(
    *urls: str, publishers: list[str] | None = None, wait: float = 10.0, **options: Any
) -> Daemon:
    """Two lines give an application its boards (thesis Listing 8.4)::

        robot = missing_link.connect("serial:///dev/ttyACM0")
        robot.subscribe("/thesis/quad", lambda update: print(update.values))

    Returns a running daemon once every board is up.  A board that is not up within ``wait``
    seconds raises ``BoardError`` naming it and why (the daemon is stopped); ``wait=0`` returns
    at once and lets boards come up in the background.  Close with ``robot.close()`` or use
    ``with missing_link.connect(...) as robot:``.  ``options`` are ``Config`` fields
    (``backoff_max=2.0``, ``distro="kilted"``, ...)."""
    if not urls:
        raise BadURL("connect() needs at least one board URL")
    cfg = Config(boards=[BoardSpec(url=u) for u in urls], publishers=publishers or ["bus"])
    for key, value in options.items():
        if not hasattr(cfg, key):
            raise TypeError(f"connect() got an unknown option {key!r}")
        setattr(cfg, key, value)
    daemon = Daemon(cfg).start()
    if wait > 0 and not daemon.wait_until_up(wait):
        down = [s for s in daemon.sessions if s.state != UP]
        daemon.stop()
        why = "; ".join(without_prefix(s.spec.url, s.error or s.state) for s in down)
        raise BoardError(", ".join(s.spec.url for s in down), f"not up within {wait:g} s: {why}")
    return daemon
