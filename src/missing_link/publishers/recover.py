"""``missing-link recover``: salvage a recording whose writer died (SIGKILL, power cut).

MCAP keeps messages in memory until their chunk is written, and the readers reject a file
without its summary.  A streaming reader still takes every complete record of it; they are
written to a new, valid bag, and the count is returned, so the user knows what was saved.

The file is input, not ours to trust (it may be anyone's): every chunk is decompressed under a
size cap (``MAX_CHUNK``, and ``MAX_RATIO`` times its compressed size: a 32 KB zstd chunk that
claims a gigabyte is refused before any work, one that grows past what it claims is stopped
there); a damaged chunk is skipped, not the rest of the file; a length that runs past the
file's end is where the file stops (reads are bounded by the file: no length makes a huge
allocation); a channel whose schema does not parse or cannot be written loses its own
messages (counted, said once), not what was salvaged of the others.  What is wrong with the
file is a :class:`RecoverError` (a ``MissingLinkError`` and a ``ValueError``: the CLI's exit
2), one line.
"""

from __future__ import annotations

import io
import logging
import shutil
import struct
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from ..errors import MissingLinkError

log = logging.getLogger(__name__)
MCAP_MAGIC = b"\x89MCAP0\r\n"
MAX_CHUNK = 64 * 2**20  #: bytes of one chunk's records, decompressed, at most
MAX_RATIO = 200  #: ... and at most this many times its compressed size (beyond 1 MiB)


class RecoverError(MissingLinkError, ValueError):
    """The file cannot be recovered (the user's input): the message says why, in one line."""


def _decompressed(chunk: Any) -> bytes | None:
    """A chunk's records, or None when it claims more than the caps allow, grows past what it
    claims, or is compressed in a way we do not read."""
    size = int(chunk.uncompressed_size)
    if size > min(MAX_CHUNK, max(2**20, MAX_RATIO * len(chunk.data))):
        return None
    # (the decompressors mcap itself reads chunks with: its dependencies, None if missing)
    from mcap import stream_reader

    zstd: Any = getattr(stream_reader, "zstandard", None)
    lz4: Any = getattr(stream_reader, "lz4", None)
    if chunk.compression == "":
        data = bytes(chunk.data)
    elif chunk.compression == "zstd" and zstd is not None:
        reader = zstd.ZstdDecompressor().stream_reader(io.BytesIO(chunk.data))
        parts, got = [], 0
        while got <= size:  # (one byte past the claim is enough to know it lied)
            part = reader.read(size + 1 - got)
            if not part:
                break
            parts.append(part)
            got += len(part)
        data = b"".join(parts)
    elif chunk.compression == "lz4" and lz4 is not None:
        data = lz4.LZ4FrameDecompressor().decompress(chunk.data, max_length=size + 1)
    else:
        return None
    return data if len(data) == size else None


def complete_messages(
    files: list[Path], skipped: Counter[str] | None = None
) -> Iterator[tuple[Any, Any, Any]]:
    """Every complete message of the MCAP file(s), as ``(schema, channel, message)`` records,
    with a streaming reader that stops at the first damaged or missing record of each file:
    exactly what a recording that died holds (``recover``), and what a failed recording
    counts as recorded.  A chunk that breaks the caps or does not decode is skipped (counted
    in ``skipped["chunks"]``), and so is a message without its channel or schema
    (``skipped["messages"]``)."""
    from mcap.exceptions import McapError
    from mcap.records import Chunk
    from mcap.stream_reader import StreamReader, breakup_chunk

    skipped = skipped if skipped is not None else Counter()
    for f in files:
        schemas: dict[int, Any] = {}
        channels: dict[int, Any] = {}
        with open(f, "rb") as raw:
            stream = _Bounded(raw)  # (a length past the file's end: a short read, no MemoryError)
            try:
                reader = StreamReader(stream, skip_magic=False, emit_chunks=True)  # type: ignore[arg-type]
                for record in reader.records:
                    inner = [record]
                    if isinstance(record, Chunk):
                        try:
                            data = _decompressed(record)
                            inner = [] if data is None else breakup_chunk(_plain(record, data))
                        except (McapError, EOFError, ValueError, struct.error, RuntimeError) as e:
                            log.info("%s: a damaged chunk skipped: %s", f, e)
                            data, inner = None, []
                        if data is None:
                            skipped["chunks"] += 1
                    yield from _messages(inner, schemas, channels, skipped)
            except (McapError, EOFError, ValueError, OSError, struct.error, OverflowError) as e:
                log.info("%s: stopped at a damaged or missing record: %s", f, e)


class _Bounded:
    """A file whose ``read(n)`` never asks for more than is left in it: a damaged length
    (2**62 bytes of a chunk's records) is a short read, then the end of the file, not an
    allocation that ends the process with MemoryError."""

    def __init__(self, f: Any) -> None:
        self._f = f
        self._size = f.seek(0, io.SEEK_END)
        f.seek(0)

    def read(self, n: int = -1) -> bytes:
        left = max(0, self._size - self._f.tell())
        return bytes(self._f.read(left if n < 0 else min(n, left)))


def _plain(chunk: Any, data: bytes) -> Any:
    from mcap.records import Chunk

    return Chunk(compression="", data=data, message_end_time=0, message_start_time=0,
                 uncompressed_crc=0, uncompressed_size=len(data))  # fmt: skip


def _messages(
    records: list[Any], schemas: dict[int, Any], channels: dict[int, Any], skipped: Counter[str]
) -> Iterator[tuple[Any, Any, Any]]:
    from mcap.records import Channel, Message, Schema

    for record in records:
        if isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, Channel):
            channels[record.id] = record
        elif isinstance(record, Message):
            ch = channels.get(record.channel_id)
            schema = schemas.get(ch.schema_id) if ch is not None else None
            if schema is None:
                skipped["messages"] += 1
            else:
                yield schema, ch, record


def count_complete(path: Path) -> int:
    """The complete messages in a bag directory's MCAP file(s)."""
    return sum(1 for _ in complete_messages(sorted(path.glob("*.mcap"))))


def recover_bag(path: str | Path, out: str | Path | None = None) -> tuple[Path, int]:
    """Salvage a recording whose writer died: read every complete record of its MCAP file(s) with
    a streaming reader, and write them to a new, valid bag.  Returns (new bag, messages)."""
    src = Path(path)
    files = sorted(src.glob("*.mcap")) if src.is_dir() else [src]
    if not files:
        raise FileNotFoundError(f"{src}: no .mcap file to recover")
    if not src.exists():
        raise FileNotFoundError(f"{src}: no such file or directory")
    for f in files:
        with open(f, "rb") as stream:
            if stream.read(8) != MCAP_MAGIC:
                raise RecoverError(f"{f}: not an MCAP file (no MCAP magic at its start)")
    dest = Path(out) if out else src.with_name(src.name.removesuffix(".mcap") + "_recovered")
    if dest.exists():
        raise FileExistsError(f"{dest} exists already; give another --out")
    skipped: Counter[str] = Counter()
    lost: Counter[str] = Counter()  # "topic (why)" -> messages not written
    count = _write_bag(dest, complete_messages(files, skipped), lost)
    for what, n in lost.items():
        log.warning("recover: %d message(s) of %s left out", n, what)
    if skipped["chunks"]:
        log.warning(
            "recover: %d chunk(s) skipped: damaged, compressed in a way not read, or over the "
            "size cap (%d MiB, %d times their compressed size)",
            skipped["chunks"], MAX_CHUNK >> 20, MAX_RATIO,
        )  # fmt: skip
    if not count:
        raise RecoverError(f"{src}: no complete message in it; nothing to recover")
    return dest, count


def _write_bag(dest: Path, messages: Iterator[tuple[Any, Any, Any]], lost: Counter[str]) -> int:
    """Write ``messages`` into a new bag at ``dest``; a channel that cannot be written loses its
    messages (into ``lost``), not the others'.  Nothing is left behind when nothing was
    written."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    from ..text import safe_text

    ts = get_typestore(Stores.ROS2_JAZZY)
    conns: dict[tuple[str, str], Any] = {}
    refused: dict[tuple[str, str], str] = {}
    count = 0
    writer = Writer(dest, version=9, storage_plugin=StoragePlugin.MCAP)
    writer.open()
    try:
        for schema, ch, record in messages:
            key = (ch.topic, schema.name)
            conn = conns.get(key)
            if conn is None and key not in refused:
                try:
                    text = schema.data.decode()
                    _register_msgdef(ts, schema.name, text, get_types_from_msg)
                    conn = conns[key] = writer.add_connection(
                        ch.topic, schema.name, msgdef=text, rihs01=ts.hash_rihs01(schema.name)
                    )
                except Exception as e:  # noqa: BLE001 - a hostile schema: its channel is lost,
                    # its messages counted (lost) and said in one line with the reason
                    refused[key] = safe_text(f"{type(e).__name__}: {e}", 120)
            if conn is None:
                lost[f"{safe_text(ch.topic, 100)} ({refused[key]})"] += 1
                continue
            writer.write(conn, record.log_time, record.data)
            count += 1
    finally:
        writer.close()
        if not count:
            shutil.rmtree(dest, ignore_errors=True)  # leave nothing half-made behind
    return count


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
