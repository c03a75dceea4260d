"""``mcap``: record every topic to rosbag2 directories with MCAP storage (rosbags' writer), readable
by rosbags' AnyReader, the ``mcap`` reader, ros2 bag and Foxglove.

Writes happen on a writer thread fed by a bounded queue (a slow disk never stalls a board; drops
are counted).  Recordings rotate by size and/or time into numbered bag directories.  A recording
whose process died before ``close()`` lacks its MCAP summary and metadata.yaml; ``recover_bag``
salvages every complete record into a new, valid bag (``missing-link recover``).
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from datetime import datetime
from pathlib import Path
from typing import Any

from ..msgs import typestore_for
from ..topics import Topic, Update
from .base import Publisher, register_publisher

log = logging.getLogger(__name__)
DIAG_TOPIC = "/diagnostics"
DIAG_TYPE = "diagnostic_msgs/msg/DiagnosticArray"


class McapPublisher(Publisher):
    name = "mcap"

    def __init__(self, options: dict[str, Any] | None = None) -> None:
        opts = options or {}
        self.base = Path(opts.get("path", "recordings"))
        self.rotate_bytes = int(float(opts.get("rotate_mb", 1024)) * 1e6)
        self.rotate_s = float(opts.get("rotate_s", 0))
        self.distro = str(opts.get("distro", "jazzy"))
        self.prefix = str(opts.get("prefix", "missing_link"))
        self.typestore = typestore_for(self.distro)
        self._q: queue.Queue[tuple[Any, ...] | None] = queue.Queue(int(opts.get("queue", 200_000)))
        self.bags: list[Path] = []
        self.messages = 0
        self.messages_by_topic: dict[str, int] = {}
        self.dropped = 0
        self._topics: dict[str, Topic] = {}
        self._writer: Any = None
        self._conns: dict[str, Any] = {}
        self._bytes = 0
        self._opened = 0.0
        self._closed = False
        self.error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="mcap-writer", daemon=True)
        self._thread.start()

    # ---- daemon side (any thread) ------------------------------------------------------------
    def add_topic(self, topic: Topic) -> None:
        self._put(("topic", topic))

    def publish(self, update: Update) -> None:
        self._put(("msg", update.topic.name, update.stamp_ns, update.cdr))

    def diagnostics(self, status: list[dict[str, Any]], now_ns: int) -> None:
        self._put(("diag", now_ns, diagnostics_cdr(self.typestore, status, now_ns)))

    def _put(self, item: tuple[Any, ...]) -> None:
        if self._closed:
            return
        try:
            self._q.put_nowait(item)
        except queue.Full:
            self.dropped += 1

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._q.put(None)
        self._thread.join(30)

    # ---- writer thread -----------------------------------------------------------------------
    def _run(self) -> None:
        try:
            while True:
                item = self._q.get()
                if item is None:
                    break
                self._handle(item)
        except BaseException as e:
            self.error = e
            log.exception("MCAP recording failed")
        finally:
            self._close_bag()

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
            _, name, stamp, data = item
            conn = self._conns.get(name)
            if conn is None:
                return
            self._writer.write(conn, stamp, data)
            self.messages_by_topic[name] = self.messages_by_topic.get(name, 0) + 1
        else:
            _, stamp, data = item
            self._writer.write(self._conns[DIAG_TOPIC], stamp, data)
        self._bytes += len(data) + 32
        self.messages += 1

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
        self._conns[DIAG_TOPIC] = writer.add_connection(
            DIAG_TOPIC, DIAG_TYPE, typestore=self.typestore
        )
        for topic in self._topics.values():
            self._connect(topic)

    def _connect(self, topic: Topic) -> None:
        if topic.name in self._conns:
            return
        topic.register_type(self.typestore)
        self._conns[topic.name] = self._writer.add_connection(
            topic.name, topic.type_name, typestore=self.typestore
        )

    def _close_bag(self) -> None:
        if self._writer is not None:
            self._writer.close()
            self._writer = None


def diagnostics_cdr(typestore: Any, status: list[dict[str, Any]], now_ns: int) -> bytes:
    """Per-board status as a ``diagnostic_msgs/msg/DiagnosticArray`` (CDR)."""
    ts = typestore
    T = ts.types
    sec, nsec = divmod(now_ns, 1_000_000_000)
    header = T["std_msgs/msg/Header"](
        stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec), frame_id=""
    )
    Status, KV = T["diagnostic_msgs/msg/DiagnosticStatus"], T["diagnostic_msgs/msg/KeyValue"]
    items = []
    for s in status:
        level = int(s.get("level", 0 if s["state"] == "up" else 2))
        values = [KV(key=str(k), value=str(v)) for k, v in s.items() if k not in ("board",)]
        items.append(
            Status(
                level=level,
                name=f"missing_link: {s['board']}",
                message=str(s.get("message") or s["state"]),
                hardware_id=str(s.get("serial", "")),
                values=values,
            )
        )
    msg = T[DIAG_TYPE](header=header, status=items)
    return bytes(ts.serialize_cdr(msg, DIAG_TYPE))


def recover_bag(path: str | Path, out: str | Path | None = None) -> tuple[Path, int]:
    """Salvage a recording whose writer died: read every complete record of its MCAP file(s) with
    a streaming reader, and write them to a new, valid bag.  Returns (new bag, messages)."""
    from mcap.exceptions import McapError
    from mcap.records import Channel, Message, Schema
    from mcap.stream_reader import StreamReader
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    src = Path(path)
    files = sorted(src.glob("*.mcap")) if src.is_dir() else [src]
    if not files:
        raise FileNotFoundError(f"{src}: no .mcap file to recover")
    dest = Path(out) if out else src.with_name(src.name.removesuffix(".mcap") + "_recovered")
    if dest.exists():
        raise FileExistsError(f"{dest} exists already; give another --out")
    ts = get_typestore(Stores.ROS2_JAZZY)
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    conns: dict[int, Any] = {}
    count = 0
    writer = Writer(dest, version=9, storage_plugin=StoragePlugin.MCAP)
    writer.open()
    try:
        for f in files:
            with open(f, "rb") as stream:
                try:
                    for record in StreamReader(stream, skip_magic=False).records:
                        if isinstance(record, Schema):
                            schemas[record.id] = record
                        elif isinstance(record, Channel):
                            channels[record.id] = record
                        elif isinstance(record, Message) and record.channel_id in channels:
                            if record.channel_id not in conns:
                                ch = channels[record.channel_id]
                                schema = schemas[ch.schema_id]
                                text = schema.data.decode()
                                _register_msgdef(ts, schema.name, text, get_types_from_msg)
                                conns[record.channel_id] = writer.add_connection(
                                    ch.topic,
                                    schema.name,
                                    msgdef=text,
                                    rihs01=ts.hash_rihs01(schema.name),
                                )
                            writer.write(conns[record.channel_id], record.log_time, record.data)
                            count += 1
                except (McapError, EOFError, ValueError, OSError) as e:
                    log.info("%s: stopped at a damaged or missing record: %s", f, e)
    finally:
        writer.close()
    return dest, count


def _register_msgdef(ts: Any, name: str, text: str, parse: Any) -> None:
    """Register a ros2msg definition with its embedded dependencies (``MSG: pkg/Type`` parts)."""
    sep = "=" * 80 + "\n"
    parts = text.split(sep)
    types = dict(parse(parts[0], name))
    for part in parts[1:]:
        header, _, body = part.partition("\n")
        dep = header.removeprefix("MSG: ").strip()
        if "/msg/" not in dep:
            dep = dep.replace("/", "/msg/", 1)
        if dep not in ts.types:
            types.update(parse(body, dep))
    ts.register({k: v for k, v in types.items() if k not in ts.types})


register_publisher("mcap", McapPublisher)
