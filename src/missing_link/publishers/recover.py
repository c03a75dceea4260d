"""``missing-link recover``: salvage a recording whose writer died (SIGKILL, power cut).

MCAP keeps messages in memory until their chunk is written, and the readers reject a file
without its summary.  A streaming reader still takes every complete record of it; they are
written to a new, valid bag, and the count is returned, so the user knows what was saved."""

from __future__ import annotations

import logging
import shutil
import struct
from collections.abc import Iterator
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)
MCAP_MAGIC = b"\x89MCAP0\r\n"


def complete_messages(files: list[Path]) -> Iterator[tuple[Any, Any, Any]]:
    """Every complete message of the MCAP file(s), as ``(schema, channel, message)`` records,
    with a streaming reader that stops at the first damaged or missing record of each file:
    exactly what a recording that died holds (``recover``), and what a failed recording
    counts as recorded."""
    from mcap.exceptions import McapError
    from mcap.records import Channel, Message, Schema
    from mcap.stream_reader import StreamReader

    for f in files:
        schemas: dict[int, Any] = {}
        channels: dict[int, Any] = {}
        with open(f, "rb") as stream:
            try:
                for record in StreamReader(stream, skip_magic=False).records:
                    if isinstance(record, Schema):
                        schemas[record.id] = record
                    elif isinstance(record, Channel):
                        channels[record.id] = record
                    elif isinstance(record, Message) and record.channel_id in channels:
                        ch = channels[record.channel_id]
                        yield schemas[ch.schema_id], ch, record
            except (McapError, EOFError, ValueError, OSError, struct.error) as e:
                log.info("%s: stopped at a damaged or missing record: %s", f, e)


def count_complete(path: Path) -> int:
    """The complete messages in a bag directory's MCAP file(s)."""
    return sum(1 for _ in complete_messages(sorted(path.glob("*.mcap"))))


def recover_bag(path: str | Path, out: str | Path | None = None) -> tuple[Path, int]:
    """Salvage a recording whose writer died: read every complete record of its MCAP file(s) with
    a streaming reader, and write them to a new, valid bag.  Returns (new bag, messages)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    src = Path(path)
    files = sorted(src.glob("*.mcap")) if src.is_dir() else [src]
    if not files:
        raise FileNotFoundError(f"{src}: no .mcap file to recover")
    if not src.exists():
        raise FileNotFoundError(f"{src}: no such file or directory")
    for f in files:
        with open(f, "rb") as stream:
            if stream.read(8) != MCAP_MAGIC:
                raise ValueError(f"{f}: not an MCAP file (no MCAP magic at its start)")
    dest = Path(out) if out else src.with_name(src.name.removesuffix(".mcap") + "_recovered")
    if dest.exists():
        raise FileExistsError(f"{dest} exists already; give another --out")
    ts = get_typestore(Stores.ROS2_JAZZY)
    conns: dict[tuple[str, str], Any] = {}
    count = 0
    writer = Writer(dest, version=9, storage_plugin=StoragePlugin.MCAP)
    writer.open()
    ok = False
    try:
        for schema, ch, record in complete_messages(files):
            key = (ch.topic, schema.name)
            conn = conns.get(key)
            if conn is None:
                text = schema.data.decode()
                _register_msgdef(ts, schema.name, text, get_types_from_msg)
                conn = conns[key] = writer.add_connection(
                    ch.topic, schema.name, msgdef=text, rihs01=ts.hash_rihs01(schema.name)
                )
            writer.write(conn, record.log_time, record.data)
            count += 1
        ok = count > 0
    finally:
        writer.close()
        if not ok:
            shutil.rmtree(dest, ignore_errors=True)  # leave nothing half-made behind
    if not count:
        raise ValueError(f"{src}: no complete message in it; nothing to recover")
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
