"""``mcap``: record every topic to rosbag2 directories with MCAP storage (rosbags' writer), readable
by rosbags' AnyReader, the ``mcap`` reader, ros2 bag and Foxglove.

Theory of operation
-------------------
Writes happen on a writer thread fed by a bounded queue (``queue`` items): a slow disk never
stalls a board; what does not fit is dropped and counted (``dropped``).  Recordings rotate by
size and/or time into numbered bag directories.

Crash safety.  MCAP keeps messages in a chunk in memory until the chunk is written; rosbags
closes a chunk at 1 MiB, which at a few hundred kB/s is many seconds of data that a SIGKILL or a
power cut would take with it.  The writer thread therefore closes the open chunk every
``chunk_s`` seconds (default 1.0) and flushes the file, so a killed process loses at most about
that much; ``missing-link recover`` salvages every complete chunk into a valid bag.  The trade
is file size and read speed: more, smaller chunks (each with its own index records).  Use
``chunk_s = 5`` for a smaller file on a robot that does not crash, ``0.2`` for a tighter bound.

Failure is loud.  The directory is created and test-written when the publisher starts: a
recording that cannot start is an error there (``PublisherError``), not a warning later.  A
write that fails (ENOSPC, EACCES, EIO) sets ``error``; the daemon reports it as ERROR in
``/diagnostics`` and ``publisher_status()``, ``run`` exits 1 and the demo fails.  After a failure
the thread keeps draining the queue and counts what it could not write as dropped, so
publishers never block; ``close()`` returns within ``close_timeout`` whatever the writer is doing.

Every message has a number.  ``messages`` counts what was handed to the writer, ``recorded``
what is in the file: a bag's messages once its chunk is flushed (or the bag closed).  When a
write fails, the bag is abandoned and its file read back with the streaming reader ``recover``
uses: ``recorded`` becomes what the file holds, the rest of the bag's messages (the open chunk
that never reached the disk, ~``chunk_s`` of data) go to ``dropped``.  So after a full disk,
``recover`` restores exactly ``recorded`` messages, and ``messages - recorded`` are in ``dropped``.

What a replay needs (``replay = true``, the default) is kept too (mcap_replay.py): the writer
closes a chunk itself before it would outgrow rosbags' 1 MiB, with room for the samples' board
stamps, so a chunk holds its samples' stamps and a file cut by SIGKILL keeps both or neither.

A board's log (docs/board-log.md) is recorded on ``/<board>/log`` as ``foxglove_msgs/msg/Log``
(``ros/logmsgs.py``), which Foxglove's Log panel reads.
"""

from __future__ import annotations

import logging
import os
import queue
import tempfile
import threading
import time
from datetime import datetime
from pathlib import Path
from typing import Any

from ..errors import ConfigError
from ..host.board_log import LogLine
from ..host.config import ConfigKey, Value
from ..ros.board_record import MESSAGES, BoardDescription
from ..ros.clock import CLOCK_MSG, CLOCK_TYPE, ClockRecord, clock_record_cdr
from ..ros.diagnostics import DIAG_TOPIC, DIAG_TYPE
from ..ros.logmsgs import FOXGLOVE_LOG, foxglove_log_cdr, log_topic
from ..topics import Topic, Update
from .base import PublisherError
from .mcap_replay import ReplayRecords, command_cdr
from .recover import count_complete
from .rosbase import RosPublisher

log = logging.getLogger(__name__)
#: rosbags closes a chunk once it is past this; the writer closes it first, stamps included
CHUNK_BYTES = 2**20
_RECORD = 64  # a message's record and index entry, at most, besides its data


def _option(opts: dict[str, Any], key: str, default: float, lo: float, hi: float) -> float:
    try:
        value = float(opts.get(key, default))
    except (TypeError, ValueError):
        raise ConfigError(f"[mcap] {key} = {opts.get(key)!r}: expected a number") from None
    if not lo <= value <= hi:
        raise ConfigError(f"[mcap] {key} = {value:g}: expected {lo:g}..{hi:g}")
    return value


class McapPublisher(RosPublisher):
    name = "mcap"

    def __init__(self, options: dict[str, Any] | None = None) -> None:
        opts = options or {}
        self.base = Path(opts.get("path", "recordings"))
        self.rotate_bytes = int(_option(opts, "rotate_mb", 1024, 0, 1e9) * 1e6)
        self.rotate_s = _option(opts, "rotate_s", 0, 0, 1e9)
        self.chunk_s = _option(opts, "chunk_s", 1.0, 0.01, 3600)
        self.close_timeout = _option(opts, "close_timeout", 10.0, 0.1, 3600)
        size = _option(opts, "queue", 200_000, 1, 1e9)
        super().__init__(str(opts.get("distro", "jazzy")))
        self.prefix = str(opts.get("prefix", "missing_link"))
        replay = opts.get("replay", True)
        if not isinstance(replay, bool):
            raise ConfigError(f"[mcap] replay = {replay!r}: expected true or false")
        #: what a replay needs (mcap_replay.py); None: not recorded
        self._replay: ReplayRecords | None = ReplayRecords() if replay else None
        _check_writable(self.base)
        self._q: queue.Queue[tuple[Any, ...] | None] = queue.Queue(int(size))
        self.bags: list[Path] = []
        self.messages = 0  #: handed to the writer
        self.recorded = 0  #: known to be in the files (flushed chunks, closed bags)
        self.messages_by_topic: dict[str, int] = {}
        self._bag_messages = 0  # handed to the writer of the current bag
        self._bag_recorded = 0  # of those, flushed to its file
        self.dropped = 0
        self.error = ""
        self._topics: dict[str, Topic] = {}
        self._own: dict[str, str] = {}  # topic -> type of our records (clock, replay's)
        self._last_stamp = 0  # the newest log time written (a stamps batch is logged at it)
        self._writer: Any = None
        self._conns: dict[str, Any] = {}
        self._bytes = 0
        self._opened = 0.0
        self._chunk_since: float | None = None  # when the open chunk got its first message
        self._closing = threading.Event()
        self._thread = threading.Thread(target=self._run, name="mcap-writer", daemon=True)
        self._thread.start()

    # ---- daemon side (any thread) ------------------------------------------------------------
    def add_topic(self, topic: Topic) -> None:
        self._put(("topic", topic))

    def publish(self, update: Update) -> None:
        self._put(("msg", update.topic.name, update.stamp_ns, update.cdr, update))

    def send_diagnostics(self, cdr: bytes, now_ns: int) -> None:
        self._put(("diag", now_ns, cdr))

    def clock_record(self, topic: str, record: ClockRecord) -> None:
        self._put(("own", topic, CLOCK_TYPE, record.t4_ns, clock_record_cdr(record)))

    def log(self, line: LogLine) -> None:
        """A board's log line on ``/<board>/log``, as Foxglove's Log panel reads it."""
        cdr = foxglove_log_cdr(
            self.typestore, line.host_ns, line.level, line.board, line.text, line.source
        )
        self._put(("own", log_topic(line.board, self._topics), FOXGLOVE_LOG, line.host_ns, cdr))

    def board_description(self, record: BoardDescription) -> None:
        if self._replay is not None:
            self._put(("replay", "describe", time.time_ns(), record))

    def add_config(
        self, board: str, keys: list[ConfigKey], values: dict[str, Value], apply: Any
    ) -> None:
        if self._replay is not None:
            self._put(("replay", "config", time.time_ns(), (board, keys, values)))

    def config_changed(self, board: str, values: dict[str, Value]) -> None:
        if self._replay is not None:
            self._put(("replay", "config", time.time_ns(), (board, None, values)))

    def command_sent(self, name: str, topic: Topic, value: Any, now_ns: int) -> None:
        if self._replay is not None:
            self._put(("replay", "command", now_ns, (name, topic, value)))

    def _put(self, item: tuple[Any, ...]) -> None:
        if self._closed:
            return
        try:
            self._q.put_nowait(item)
        except queue.Full:
            self.dropped += 1

    def shutdown(self) -> None:
        self._closing.set()
        try:
            self._q.put_nowait(None)
        except queue.Full:
            pass  # the writer sees _closing after the queue's current contents
        self._thread.join(self.close_timeout)
        if self._thread.is_alive():
            left = self._q.qsize()
            self.dropped += left
            self._fail(f"writer did not finish within {self.close_timeout:g} s ({left} queued)")

    def status(self) -> dict[str, Any]:
        out = super().status()
        out.update(
            messages=self.messages,
            recorded=self.recorded,
            queued=self._q.qsize(),
            path=str(self.bags[-1]) if self.bags else str(self.base),
        )
        return out

    # ---- writer thread -----------------------------------------------------------------------
    def _run(self) -> None:
        try:
            while True:
                try:
                    item = self._q.get(timeout=self._wait())
                except queue.Empty:
                    item = ()
                if item is None or (not item and self._closing.is_set() and self._q.empty()):
                    break
                if self.error:
                    if item and item[0] != "topic":
                        self.dropped += 1  # failed for good: count, never block
                    continue
                try:
                    if item:
                        self._handle(item)
                    self._maybe_close_chunk()
                except Exception as e:  # noqa: BLE001 - any write failure is loud (ERROR) and
                    self._failed(e, "write", _describe(e, self.base))  # counted; it goes on
        finally:
            try:
                self._close_bag()
            except Exception as e:  # noqa: BLE001 - (as a write's)
                self._failed(e, "close", f"closing the bag failed: {_describe(e, self.base)}")

    def _failed(self, e: Exception, where: str, text: str) -> None:
        if not isinstance(e, OSError):  # not the disk: a bug, counted by kind, traceback said
            self.faults.caught(where, e)
        self._fail(text)
        self._abandon_bag()

    def _wait(self) -> float:
        if self._chunk_since is None:
            return 0.5
        return max(0.0, self._chunk_since + self.chunk_s - time.monotonic())

    def _fail(self, text: str) -> None:
        if not self.error:
            self.error = f"recording failed: {text}"
            log.error("mcap: %s", self.error)

    def _maybe_close_chunk(self) -> None:
        since = self._chunk_since
        if since is None or time.monotonic() - since < self.chunk_s:
            return
        self._close_chunk()

    def _close_chunk(self) -> None:
        """Write the pending stamps, then the chunk and its indexes, and flush the file."""
        self._write_stamps()
        storage = getattr(self._writer, "storage", None)
        if storage is not None and hasattr(storage, "close_chunk") and storage.chunk.bio.tell():
            storage.close_chunk()  # rosbags' MCAP storage: write the chunk and its indexes
            storage.bio.flush()
        self._flushed()
        self._chunk_since = None

    def _flushed(self) -> None:
        """Everything handed to the writer so far is in the file."""
        self.recorded += self._bag_messages - self._bag_recorded
        self._bag_recorded = self._bag_messages

    def _abandon_bag(self) -> None:
        """A write failed: close the file as it stands and count what it holds, exactly as
        ``recover`` will find it; the bag's other messages are dropped."""
        writer, self._writer = self._writer, None
        if writer is not None:
            try:
                writer.abort()  # (closes the file; what its buffer still held may fail too)
            except Exception as e:  # noqa: BLE001 - it failed already (said); the count below
                log.debug("mcap: closing the failed bag: %s", e)  # says what is in it
        if not self._bag_messages or not self.bags:
            return
        try:
            in_file = count_complete(self.bags[-1])
        except OSError as e:
            log.warning("mcap: cannot read back %s: %s", self.bags[-1], e)
            in_file = self._bag_recorded  # what was flushed before the failure
        self.recorded += in_file - self._bag_recorded
        self.dropped += self._bag_messages - in_file
        self._bag_messages = self._bag_recorded = 0

    def _handle(self, item: tuple[Any, ...]) -> None:
        kind = item[0]
        if kind == "topic":
            topic: Topic = item[1]
            self._topics[topic.name] = topic
            if self._writer is not None:
                self._connect(topic)
            return
        if self._writer is None or self._due_rotation():
            self._rotate()
        if kind == "msg":
            _, name, stamp, data, update = item
            conn = self._conns.get(name)
            if conn is None:
                return
            replay = self._replay
            stamped = replay is not None and update.topic.encoder is not None
            self._write(name, conn, stamp, data, 11 + 8 * len(update.board_us) if stamped else 0)
            if stamped:  # (a thesis-format topic: a replay derives the standard ones again)
                assert replay is not None
                replay.sample(update.topic, update.seq, update.board_us, update.bound_ns)
        elif kind == "own":
            _, name, type_name, stamp, data = item
            self._write(name, self._connect_own(name, type_name), stamp, data)
        elif kind == "replay":
            self._handle_replay(item[1], item[2], item[3])
        else:
            _, stamp, data = item
            self._write(DIAG_TOPIC, self._conns[DIAG_TOPIC], stamp, data, count=False)

    def _handle_replay(self, what: str, stamp: int, arg: Any) -> None:
        replay = self._replay
        assert replay is not None
        if what == "describe":
            records = [replay.describe(arg)]
        elif what == "config":
            got = replay.config(*arg)
            records = [got] if got is not None else []
        else:
            name, topic, value = arg
            self._command(name, topic, value, stamp)
            return
        for name, type_name, data in records:
            self._write(name, self._connect_own(name, type_name), stamp, data)

    def _command(self, name: str, topic: Topic, value: Any, now_ns: int) -> None:
        """An actuator command on ``name``, in the actuator's own type (mcap_replay.py)."""
        if topic.encoder is None:
            return
        data = command_cdr(topic, value, now_ns)
        if data is None:
            self.dropped += 1  # (the daemon took it: a value our encoder cannot carry is a bug)
            return
        if name not in self._conns:
            topic.register_type(self.typestore)
            self._conns[name] = self._writer.add_connection(
                name, topic.type_name, typestore=self.typestore
            )
            self._own[name] = topic.type_name
        self._write(name, self._conns[name], now_ns, data)

    def _write(
        self, name: str, conn: Any, stamp: int, data: bytes, also: int = 0, count: bool = True,
        room: bool = True,
    ) -> None:  # fmt: skip
        """Write one message (``also``: bytes of stamps it brings); the chunk is closed first
        when it would outgrow rosbags' limit with the pending stamps (they stay with it).
        ``room`` False: the pending stamps themselves (their room is kept)."""
        storage = getattr(self._writer, "storage", None)
        chunk = getattr(storage, "chunk", None)
        if room and self._replay is not None and chunk is not None:
            pending = self._replay.pending_bytes + also + 2 * _RECORD
            if chunk.bio.tell() + len(data) + pending > CHUNK_BYTES:
                self._close_chunk()
        # counted before the write: a write that fails may still have put it in the file
        # (the read-back after a failure says; see _abandon_bag)
        self.messages += 1
        self._bag_messages += 1
        self._writer.write(conn, stamp, data)
        self._last_stamp = max(self._last_stamp, stamp)
        if count:
            self.messages_by_topic[name] = self.messages_by_topic.get(name, 0) + 1
        if self._chunk_since is None:
            self._chunk_since = time.monotonic()
        self._bytes += len(data) + 32

    def _write_stamps(self) -> None:
        if self._replay is None or self._writer is None:
            return
        for name, type_name, data in self._replay.take_stamps():
            conn = self._connect_own(name, type_name)
            self._write(name, conn, self._last_stamp, data, room=False)

    def _due_rotation(self) -> bool:
        if self.rotate_bytes and self._bytes >= self.rotate_bytes:
            return True
        return bool(self.rotate_s) and time.monotonic() - self._opened >= self.rotate_s

    def _rotate(self) -> None:
        from rosbags.rosbag2 import StoragePlugin, Writer

        self._close_bag()
        self.base.mkdir(parents=True, exist_ok=True)
        stamp = datetime.now().strftime("%Y%m%d_%H%M%S")
        path = self.base / f"{self.prefix}_{stamp}_{len(self.bags):03d}"
        writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
        writer.open()
        self._writer = writer
        self.bags.append(path)
        self._conns = {}
        self._bytes = 0
        self._opened = time.monotonic()
        self._chunk_since = None
        self._conns[DIAG_TOPIC] = writer.add_connection(
            DIAG_TOPIC, DIAG_TYPE, typestore=self.typestore
        )
        for topic in self._topics.values():
            self._connect(topic)
        for name, type_name in self._own.items():
            self._connect_own(name, type_name)
        if self._replay is not None:  # every bag replays alone
            for name, type_name, data in self._replay.again():
                self._write(name, self._connect_own(name, type_name), time.time_ns(), data)

    def _connect(self, topic: Topic) -> None:
        if topic.name in self._conns:
            return
        topic.register_type(self.typestore)
        self._conns[topic.name] = self._writer.add_connection(
            topic.name, topic.type_name, typestore=self.typestore
        )

    def _connect_own(self, name: str, type_name: str) -> Any:
        """The connection of one of our records' topics (clock, replay's), made on first use."""
        conn = self._conns.get(name)
        if conn is not None:
            return conn
        if type_name not in self.typestore.types:
            from rosbags.typesys import get_types_from_msg

            text = CLOCK_MSG if type_name == CLOCK_TYPE else MESSAGES[type_name]
            self.typestore.register(get_types_from_msg(text, type_name))
        self._own[name] = type_name
        conn = self._conns[name] = self._writer.add_connection(
            name, type_name, typestore=self.typestore
        )
        return conn

    def _close_bag(self) -> None:
        """Close the bag (its stamps, last chunk, indexes, footer): every message is in the
        file.  When this raises, the writer is still set, so ``_abandon_bag`` closes and
        counts the file."""
        writer = self._writer
        if writer is None:
            return
        self._write_stamps()
        writer.close()
        self._writer = None
        self._flushed()
        self._bag_messages = self._bag_recorded = 0


def _check_writable(base: Path) -> None:
    """Fail at startup, with the reason, when ``base`` cannot hold a recording."""
    try:
        base.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".missing-link-probe-", dir=base)
        os.close(fd)
        os.unlink(probe)
    except OSError as e:
        raise PublisherError(f"cannot record to {base}: {e.strerror or e}") from None


def _describe(e: BaseException, base: Path) -> str:
    if isinstance(e, OSError) and e.strerror:
        return f"{e.strerror} ({base})"
    return f"{type(e).__name__}: {e}"
