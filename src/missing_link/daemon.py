"""The missing-link daemon: boards in, typed topics out.

Theory of operation
-------------------
One ``BoardSession`` per configured board runs a supervisor thread through these states:

    connecting --open+describe ok--> up --link lost--> backoff --delay--> connecting
         \\--fails (no board, bad descriptors)--------> backoff
    any state --stop()--> stopped

In ``connecting`` the session opens the URL, reads the mapping, properties and descriptors
(or takes them from a host-side file for original boards), declares one topic per transducer
(``/<board>/<name>``, remappable) to every publisher, and registers ``/<board>/<name>/cmd`` for
actuators.  In ``up`` the board's reader thread decodes every sample SIF into an ``Update`` and
hands it to every publisher; the supervisor thread meanwhile runs actuator commands (latest
command per actuator wins, so a slow board never builds a backlog, and a subscriber callback
can never deadlock the reader) and measures the RPC round trip every diagnostics period.  When
the link breaks the session waits with exponential backoff (``backoff_min`` doubling up to
``backoff_max``) and reconnects.  Sessions share nothing but the publishers: one broken board
never stops another.

Host time: each session runs a :class:`~missing_link.timesync.ClockSync` on the board's
``a2jClock`` (or the thesis firmware's ``getTime``).  On connect a short burst of exchanges gives
the first estimate before any sample is published; then the supervisor thread probes on the
sync's schedule, and every sample's board stamps go through the published map (continuous,
strictly increasing) into CLOCK_REALTIME ns, with a 1-sigma estimate and a hard bound on the
update.  A board time far behind the newest one mapped, or an exchange whose board time went
backwards, is a board reset: the map restarts (the next update is flagged ``STEP``) and samples
until the new estimate are flagged ``NOT_SYNCED`` (host time = receive time, bound unknown).
Boards with neither function get the receive time and ``NOT_SYNCED`` on every sample.  Boards
with ``a2jHostMap`` are handed the current estimate once a second, so they can act at a host
time (``Daemon.trigger_at``).
"""

from __future__ import annotations

import logging
import struct
import threading
import time
from collections.abc import Iterable
from typing import Any

from .client import Board
from .config import BoardSpec, Config
from .descriptors import Transducer, load_descriptor_file
from .errors import CallTimeout, MissingLinkError
from .j2a import SifReceived
from .msgs import typestore_for
from .publishers import Bus, Publisher, make_publisher
from .publishers.bus import Callback, Subscription
from .standard import StandardMapping, mapping_for
from .timesync import NOT_SYNCED, AddResult, ClockSync, SyncOptions
from .topics import Topic, Update

log = logging.getLogger(__name__)

CONNECTING, UP, BACKOFF, STOPPED = "connecting", "up", "backoff", "stopped"


class BoardSession:
    def __init__(self, daemon: Daemon, spec: BoardSpec) -> None:
        self.daemon = daemon
        self.spec = spec
        self.state = CONNECTING
        self.error = ""
        self.name = spec.name or spec.url
        self.board: Board | None = None
        self.topics: dict[int, Topic] = {}  # transducer id -> topic
        self.standard: dict[int, tuple[Topic, StandardMapping]] = {}  # id -> standard-type topic
        self.warnings: list[str] = []
        self.connects = 0
        self.samples = 0
        self.updates = 0
        self.unknown_sifs = 0
        self.bad_sifs = 0
        self.commands = 0
        self.command_errors = 0
        self.rtt_us: float | None = None
        self.sync: ClockSync | None = None
        self.epoch = ""
        self.map_pushes = 0
        self._next_push = 0.0
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._pending: dict[str, tuple[Transducer, Any]] = {}  # latest command per actuator
        self._pending_lock = threading.Lock()
        self._thread = threading.Thread(
            target=self._supervise, name=f"session:{spec.url}", daemon=True
        )

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._wake.set()
        if self.board is not None:
            self.board.close()
        self._thread.join(10)
        self.state = STOPPED

    # ---- supervisor thread -------------------------------------------------------------------
    def _supervise(self) -> None:
        delay = self.daemon.config.backoff_min
        while not self._stop.is_set():
            self.state = CONNECTING
            try:
                self._connect()
            except MissingLinkError as e:
                self.error = str(e)
                log.warning("%s: %s", self.spec.url, e)
            else:
                delay = self.daemon.config.backoff_min
                self._serve()
            finally:
                self._disconnect()
            if self._stop.is_set():
                break
            self.state = BACKOFF
            self._stop.wait(delay)
            delay = min(delay * 2, self.daemon.config.backoff_max)
        self.state = STOPPED

    def _connect(self) -> None:
        board = Board.open(
            self.spec.url, timeout=self.spec.timeout, describe=not self.spec.descriptors
        )
        self.board = board
        if self.spec.descriptors:
            transducers = load_descriptor_file(self.spec.descriptors)
        elif board.transducers is None:
            raise MissingLinkError(
                f"{board.name}: original board without descriptors; give them with "
                'descriptors = "FILE" in its [[board]] table'
            )
        else:
            transducers = board.transducers
        self.name = self.spec.name or board.name
        cfg = self.daemon.config
        self._start_sync(board)
        self.topics = {}
        self.standard = {}
        self.warnings = []
        for t in transducers:
            topic_name = cfg.remap.get(f"/{self.name}/{t.name}", f"/{self.name}/{t.name}")
            topic = Topic.for_transducer(topic_name, self.name, t, cfg.package)
            self.topics[t.id] = topic
            self.daemon._declare(topic)
            try:
                mapping = mapping_for(t, self.name, self.daemon.typestore)
            except ValueError as e:
                self.warnings.append(str(e))
                log.warning("%s", e)
                mapping = None
            if mapping is not None:
                std = Topic.standard_type(
                    f"{topic_name}/{mapping.suffix}",
                    self.name,
                    t,
                    mapping.type_name,
                    self.daemon.typestore,
                )
                self.standard[t.id] = (std, mapping)
                self.daemon._declare(std)
            if t.is_actuator:
                if t.call not in board.index:
                    raise MissingLinkError(
                        f"{self.name}: actuator {t.name} names call={t.call}, which the board lacks"
                    )
                handler = self._command_handler(t)
                self.daemon.bus.add_command(f"{topic_name}/cmd", handler)
                for p in self.daemon.publishers:
                    p.add_command_topic(f"{topic_name}/cmd", topic, handler)
        board.on_sif(None, self._on_sif)
        self.connects += 1
        self.error = ""
        self.state = UP
        log.info("%s: up as %s with %d topics", self.spec.url, self.name, len(self.topics))

    def _serve(self) -> None:
        period = self.daemon.config.diagnostics_period
        next_ping = time.monotonic()
        board = self.board
        assert board is not None
        while not self._stop.is_set() and board.alive:
            due = next_ping if self.sync is None else min(next_ping, self.sync.due())
            self._wake.wait(max(0.0, min(0.1, due - time.monotonic())))
            self._wake.clear()
            self._run_commands(board)
            now = time.monotonic()
            if self.sync is not None and now >= self.sync.due():
                self._probe(board, now)
            if now >= next_ping:
                next_ping += period
                if self.sync is None:  # no clock exchanges to measure the round trip with
                    try:
                        t0 = time.perf_counter()
                        board.call("a2jEcho", b"", timeout=self.spec.timeout)
                        self.rtt_us = (time.perf_counter() - t0) * 1e6
                    except MissingLinkError as e:
                        self.error = str(e)
        if not board.alive and not self._stop.is_set():
            self.error = f"link lost: {board.transport.url}"

    # ---- clock synchronisation ---------------------------------------------------------------
    def _start_sync(self, board: Board) -> None:
        self.sync = None
        if "a2jClock" not in board.index and "getTime" not in board.index:
            self.warnings.append(
                "no a2jClock or getTime: host times are receive times, without a bound"
            )
            return
        try:
            res = int(board.properties.get("clock.res_us", "1") or 1)
        except ValueError:
            res = 1
        self.epoch = board.properties.get("clock.epoch", "")
        sync = ClockSync(SyncOptions(res_us=res), seed=hash(self.spec.url) & 0xFFFF)
        sync.start(time.monotonic())
        # A first estimate before any sample is published: a few back-to-back exchanges.
        for _ in range(8):
            self._probe(board, time.monotonic(), sync)
        self.sync = sync
        self._next_push = 0.0

    def _probe(self, board: Board, now: float, sync: ClockSync | None = None) -> None:
        sync = sync or self.sync
        assert sync is not None
        try:
            ex = board.clock_exchange(self.spec.timeout, byte_ns=self.spec.byte_ns)
        except CallTimeout:
            sync.on_lost(time.monotonic())
            return
        except MissingLinkError as e:
            self.error = str(e)
            sync.on_lost(time.monotonic())
            return
        result = sync.on_exchange(ex, time.monotonic())
        self.rtt_us = ex.rtt_ns / 1000
        if result is AddResult.RESET:
            log.warning(
                "%s: board clock went backwards: board reset, clock map restarted", self.name
            )
        if "a2jHostMap" in board.index and time.monotonic() >= self._next_push:
            self._push_map(board, sync)

    def _push_map(self, board: Board, sync: ClockSync) -> None:
        got = sync.host_map()
        if got is None:
            return
        b, h, rate = got
        ppb = round((rate / 1000.0 - 1.0) * 1e9)
        payload = struct.pack("<Qqi", b, round(h) + self.daemon.realtime_offset_ns, ppb)
        try:
            board.call_ok("a2jHostMap", payload, timeout=self.spec.timeout)
            self.map_pushes += 1
            self._next_push = time.monotonic() + 1.0
        except MissingLinkError as e:
            self.error = str(e)

    def _disconnect(self) -> None:
        for topic in self.topics.values():
            self.daemon.bus.remove_command(f"{topic.name}/cmd")
        if self.board is not None:
            self.board.close()

    # ---- actuators ---------------------------------------------------------------------------
    def _command_handler(self, t: Transducer) -> Any:
        def handler(value: Any) -> None:
            if isinstance(value, Update):
                present = [v for v in value.values if v is not None]
                if not present:
                    raise ValueError(f"{t.name}: the update on {value.topic.name} has no value")
                value = present[0]
            elif isinstance(value, (list, tuple)):
                value = value[0]
            if not t.legal(value):
                raise ValueError(f"{t.name}: {value!r} is not a legal {t.dtype} command")
            with self._pending_lock:
                self._pending[t.name] = (t, value)
            self._wake.set()

        return handler

    def _run_commands(self, board: Board) -> None:
        with self._pending_lock:
            pending, self._pending = self._pending, {}
        for t, value in pending.values():
            try:
                board.call_ok(str(t.call), t.value_struct().pack(value))
                self.commands += 1
            except MissingLinkError as e:
                self.command_errors += 1
                self.error = str(e)
                log.warning("%s", e)
            except struct.error as e:
                self.command_errors += 1
                log.warning("%s: bad command value %r: %s", t.name, value, e)

    # ---- the sample path (board reader thread) -----------------------------------------------
    def _on_sif(self, sif: SifReceived, now_mono: float) -> None:
        topic = self.topics.get(sif.cmd)
        if topic is None:
            self.unknown_sifs += 1
            return
        try:
            board_us, values = topic.transducer.decode_columns(sif.payload)
        except ValueError:
            self.bad_sifs += 1
            return
        recv_ns = int(now_mono * 1e9)
        rt_off = self.daemon.realtime_offset_ns
        missing = values.count(None)
        sync = self.sync
        got = None
        if sync is not None:
            resets = sync.resets
            got = sync.map_many(board_us, now_mono)
            if sync.resets != resets:
                log.warning("%s: sample stamps went back: board reset, map restarted", self.name)
        if got is not None:
            hosts, sigma, bound, flags = got
            host_ns = [0 if v is None else h + rt_off for h, v in zip(hosts, values, strict=True)]
        else:  # no clock map (yet): the receive time, flagged, without a bound
            sigma, bound, flags = -1, -1, NOT_SYNCED
            host_ns = [0 if v is None else recv_ns + rt_off for v in values]
        # All channels N/A: log at the arrival time (never at 0 or a monotonic stamp).
        stamp = recv_ns + rt_off if missing == len(values) else None
        update = Update(
            topic,
            board_us,
            host_ns,
            values,
            sif.seq,
            sif.lost,
            recv_ns,
            None,
            stamp,
            bound,
            sigma,
            flags,
        )
        self.updates += 1
        self.samples += len(values) - missing
        self.daemon._publish(update)
        std = self.standard.get(sif.cmd)
        if std is not None:
            std_topic, mapping = std
            for ch, v in enumerate(values):
                if v is not None:
                    cdr = mapping.build(ch, host_ns[ch], v)
                    self.daemon._publish(
                        Update(
                            std_topic,
                            [board_us[ch]],
                            [host_ns[ch]],
                            [v],
                            sif.seq,
                            0,
                            recv_ns,
                            cdr,
                            None,
                            bound,
                            sigma,
                            flags,
                        )
                    )

    def status(self) -> dict[str, Any]:
        b = self.board
        d = b.conn.decoder.stats if b else None
        c = b.conn.stats if b else None
        return {
            "board": self.name,
            "url": self.spec.url,
            "state": self.state,
            "error": self.error,
            "serial": b.properties.get("board.serial", "") if b else "",
            "connects": self.connects,
            "samples": self.samples,
            "frames": d.frames if d else 0,
            "bad_checksums": d.bad_checksums if d else 0,
            "bad_escapes": d.bad_escapes if d else 0,
            "cut_frames": d.cut_frames if d else 0,
            "junk_bytes": d.junk_bytes if d else 0,
            "lost_sifs": c.sifs_lost if c else 0,
            "timeouts": c.timeouts if c else 0,
            "unknown_sifs": self.unknown_sifs,
            "commands": self.commands,
            "command_errors": self.command_errors,
            "rtt_us": round(self.rtt_us) if self.rtt_us is not None else None,
            "warnings": "; ".join(self.warnings),
            "clock_epoch": self.epoch,
            "map_pushes": self.map_pushes,
            **(self.sync.status() if self.sync is not None else {"sync_state": "none"}),
        }


class Daemon:
    """Connects every configured board and publishes its transducers.  Use as a context manager."""

    def __init__(self, config: Config, extra_publishers: Iterable[Publisher] = ()) -> None:
        self.config = config
        self.bus = Bus()
        self.publishers: list[Publisher] = [self.bus]
        for name in config.publishers:
            if name != "bus":
                self.publishers.append(make_publisher(name, self._options(name)))
        self.publishers.extend(extra_publishers)
        self.sessions = [BoardSession(self, spec) for spec in config.boards]
        self.realtime_offset_ns = time.time_ns() - time.monotonic_ns()
        self.typestore = typestore_for(config.distro)
        self._stop = threading.Event()
        self._diag_thread = threading.Thread(
            target=self._diagnostics, name="diagnostics", daemon=True
        )
        self.publish_errors = 0

    def _options(self, name: str) -> dict[str, Any]:
        opts = dict(self.config.publisher_options.get(name, {}))
        opts.setdefault("distro", self.config.distro)
        if name in ("zenoh", "ros1"):
            opts.setdefault("node", self.config.node)
        return opts

    def start(self) -> Daemon:
        for s in self.sessions:
            s.start()
        self._diag_thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        for s in self.sessions:
            s.stop()
        if self._diag_thread.is_alive():
            self._diag_thread.join(5)
        for p in self.publishers:
            try:
                p.close()
            except Exception:
                log.exception("closing publisher %s failed", p.name)

    def __enter__(self) -> Daemon:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ---- for applications (the thesis's Listing 8.4) -----------------------------------------
    def subscribe(self, topic: str, callback: Callback) -> Subscription:
        return self.bus.subscribe(topic, callback)

    def send(self, topic: str, value: Any) -> None:
        self.bus.send(topic, value)

    def trigger_at(
        self, host_ns: int, boards: Iterable[str] | None = None, function: str = "setTriggerAt"
    ) -> dict[str, int]:
        """Have boards act at one host time (CLOCK_REALTIME ns), each at its own tick.

        Each board is first handed the current clock map (``a2jHostMap``); ``function`` (i64
        host ns) converts it on the board.  Returns board name -> the board tick it chose."""
        wanted = set(boards) if boards is not None else None
        ticks: dict[str, int] = {}
        for s in self.sessions:
            b, sync = s.board, s.sync
            if wanted is not None and s.name not in wanted:
                continue
            if s.state != UP or b is None or sync is None:
                raise MissingLinkError(f"{s.name}: not up with a clock map; cannot trigger")
            s._push_map(b, sync)
            reply = b.call_ok(function, struct.pack("<q", host_ns))
            ticks[s.name] = struct.unpack("<Q", reply[:8])[0] if len(reply) >= 8 else -1
        return ticks

    def wait_until_up(self, timeout: float = 10.0) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if all(s.state == UP for s in self.sessions):
                return True
            time.sleep(0.02)
        return False

    def status(self) -> list[dict[str, Any]]:
        return [s.status() for s in self.sessions]

    # ---- internals -------------------------------------------------------------------------
    def _declare(self, topic: Topic) -> None:
        for p in self.publishers:
            p.add_topic(topic)

    def _publish(self, update: Update) -> None:
        for p in self.publishers:
            try:
                p.publish(update)
            except Exception:
                self.publish_errors += 1
                log.exception("publisher %s failed", p.name)

    def _diagnostics(self) -> None:
        while not self._stop.wait(self.config.diagnostics_period):
            status = self.status()
            now = time.time_ns()
            for p in self.publishers:
                try:
                    p.diagnostics(status, now)
                except Exception:
                    log.exception("publisher %s failed on diagnostics", p.name)


def connect(*urls: str, publishers: list[str] | None = None, **options: Any) -> Daemon:
    """Two lines give an application its boards (thesis Listing 8.4)::

    robot = missing_link.connect("serial:///dev/ttyACM0")
    robot.subscribe("/thesis/quad", lambda update: print(update.values))
    """
    cfg = Config(boards=[BoardSpec(url=u) for u in urls], publishers=publishers or ["bus"])
    for key, value in options.items():
        if not hasattr(cfg, key):
            raise TypeError(f"connect() got an unknown option {key!r}")
        setattr(cfg, key, value)
    daemon = Daemon(cfg).start()
    daemon.wait_until_up(10.0)
    return daemon
