"""The missing-link daemon: boards in, typed topics out.

Theory of operation
-------------------
The daemon owns the publishers and one :class:`~missing_link.daemon.session.session.BoardSession`
per configured board; the session module says how a board is connected, validated, served and
reconnected, and how its host times are made.  A session is handed a
:class:`~missing_link.daemon.session.context.SessionContext` (``session_context()``: a few
values, the daemon's claims and its fan-out, each behind a narrow interface), never the
daemon.  The daemon's own job is the fan-out and what sessions must agree
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

import logging
import threading
from collections.abc import Iterable
from concurrent.futures import Future
from typing import Any

from ..descriptors import load_descriptor_file
from ..errors import BadURL, BoardError, MissingLinkError, without_prefix
from ..host.clock import SYSTEM_CLOCK, Clock
from ..host.reactor import Reactor
from ..logs import ErrorCounts
from ..publishers.base import DaemonApi, Publisher, PublisherError
from ..publishers.bus import Bus, Callback, LogCallback, Subscription
from ..publishers.registry import daemon_settings, make_publisher
from ..ros.msgs import typestore_for
from ..text import did_you_mean
from ..topics import Command
from ..transport import check_url
from .board_api import BoardApi
from .claims import Claims
from .config import BoardSpec, Config
from .control.allowlist import CommandGate
from .control.endpoint import ControlServer
from .control.ops import control_handlers
from .fanout import Fanout
from .health import publisher_rows
from .intake.dialin import DialIns
from .intake.discovery import DiscoveryService, Enumerator, all_ports
from .joints import Joints
from .names import NameCheck
from .session.context import SessionContext
from .session.link import Mailbox
from .session.session import BoardSession
from .session.status import SessionState, SessionStatus

log = logging.getLogger(__name__)

__all__ = ["BoardSession", "Daemon", "connect"]


class Daemon(BoardApi):
    """Connects every configured board and publishes its transducers.  Use as a context manager."""

    def __init__(
        self,
        config: Config,
        extra_publishers: Iterable[Publisher] = (),
        enumerate_ports: Enumerator | None = None,
        *,
        clock: Clock = SYSTEM_CLOCK,
    ) -> None:
        """``clock``: the daemon's one time source (host/clock.py), handed to the I/O loop,
        the sessions (their supervisors, liveness, background reads), the listener, discovery,
        updates and joints; a test hands a ``missing_link.testing.FakeClock``."""
        self.config = config
        self.clock = clock
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
                self.dialins = DialIns(config, listen, self.add_board, clock, self.forget)
        except BaseException:  # (broad, raised again: whatever stops the start, none is left)
            for p in self.publishers:  # a publisher that cannot start fails the daemon at once
                p.close()
            raise
        self.publishers.extend(extra_publishers)
        # one I/O loop reads every board on a descriptor (see reactor.py); it gathers streaming
        # SIFs for the smallest batch_ms any board asks for
        batch_ms = min((b.batch_ms for b in config.boards), default=BoardSpec.batch_ms)
        self.reactor = Reactor(batch_s=batch_ms / 1000, clock=clock)
        self.realtime_offset_ns = clock.realtime_ns() - clock.monotonic_ns()
        self.typestore = typestore_for(config.distro)
        self.claims = Claims(config.package, {n: i for n, i in config.board_ids.items() if i})
        self.fanout = Fanout(self.publishers, self.bus, self.commands, self.configure)
        self.joints: Joints | None = None  #: the robot-level JointState ([joints]; joints.py)
        if config.joints is not None and config.joints.joints:
            self.joints = Joints(config.joints, config.remap, self.typestore, self.fanout.publish,
                                 self.fanout.route, self._actuator, clock)  # fmt: skip
            self.publishers.append(self.joints)
        self._context = self.session_context()
        self.names = NameCheck(config)  #: configured names that match nothing (names.py)
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
                config.discover, ports, self.add_board, self.remove_board, clock
            )

    @property
    def publish_errors(self) -> int:
        """Calls into a publisher that raised (the fan-out's count; each publisher's status
        has its own by kind)."""
        return self.fanout.errors

    def _options(self, name: str) -> dict[str, Any]:
        opts = dict(self.config.publisher_options.get(name, {}))
        for key in daemon_settings(name):  # (what the face declares it takes: registry.py)
            opts.setdefault(key, getattr(self.config, key))
        return opts

    def start(self) -> Daemon:
        """Start every session (idempotent: ``with connect(...)`` starts nothing twice)."""
        if self._started:
            return self
        self._started = True
        api = DaemonApi(self.status, self.publisher_status, self.configure, self.reset_config,
                        self.fanout.declare, self.fanout.add_command)  # fmt: skip
        for p in self.publishers:  # (every face, before any board: base.py)
            p.start(api)
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
                handlers = control_handlers(*verbs, self.fanout.log, self.clock, self.gate_board)
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
        gone = [s for s in self.sessions if s.spec.url == url]
        self.forget(gone, timeout)
        return bool(gone)

    def forget(self, sessions: list[BoardSession], timeout: float = 1.0) -> None:
        """End these sessions (all asked at once) and free their names: boards that are gone
        for good (a device that vanished, an unknown id that dialed in and left)."""
        with self._sessions_lock:
            self.sessions = [s for s in self.sessions if all(s is not g for g in sessions)]
        for s in sessions:
            s.request_stop()
        deadline = self.clock.monotonic() + timeout
        for s in sessions:
            s.stop(max(0.0, deadline - self.clock.monotonic()))
            self.claims.release(s)

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
        now = self.clock.monotonic
        deadline = now() + 1.0
        for s in self.sessions:
            s.stop(max(0.0, deadline - now()))
        if self._diag_thread.is_alive():
            self._diag_thread.join(max(0.05, deadline - now()))
        self.reactor.stop(max(0.05, deadline - now()))
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
            near = did_you_mean(topic, self.bus.topics)
            raise KeyError(
                f"no topic {topic!r}{near}: every board is up and none has it (topics: {known})"
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
        return (
            self.discovery is None
            and bool(sessions)
            and all(s.state == SessionState.UP for s in sessions)
        )

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

    def wait_until_up(self, timeout: float = 10.0) -> bool:
        deadline = self.clock.monotonic() + timeout
        while self.clock.monotonic() < deadline:
            if all(s.state == SessionState.UP for s in self.sessions):
                return True
            self.clock.wait(self._stop, 0.02)
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
            probe_gap=lambda: self.probe_gap,
            claims=self.claims,
            faces=self.fanout,  # (each face changes a configuration as itself: fanout.py)
            clock=self.clock,
        )

    def _diagnostics(self) -> None:
        while not self._stop.wait(self.config.diagnostics_period):
            if self.dialins is not None:
                self.dialins.sweep()  # (unknown ids gone for dialin_expire: removed)
            up = {s.name: [t.transducer.name for t in s.topics.values()]
                  for s in self.sessions if s.state == SessionState.UP}  # fmt: skip
            self.names.check(up, self._all_boards_known())
            self.fanout.diagnostics(
                self.status() + self.publisher_status(), self.clock.realtime_ns()
            )


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
        down = [s for s in daemon.sessions if s.state != SessionState.UP]
        daemon.stop()
        why = "; ".join(without_prefix(s.spec.url, s.error or s.state) for s in down)
        raise BoardError(", ".join(s.spec.url for s in down), f"not up within {wait:g} s: {why}")
    return daemon
