"""Recordings crafted from a real one, for the attacks on ``replay``
(tests/test_replay_crafted.py): every record copied with the ``mcap`` package's own reader and
writer (nothing of ours), each one handed to an edit that may change its bytes, drop it or add
records after it."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from pathlib import Path

from mcap.reader import make_reader
from mcap.writer import Writer

#: (schema name, topic, log time ns, data) -> what to write in its place: (topic, log time, data)
#: per record (the same topic's schema and channel), [] to drop it
Edit = Callable[[str, str, int, bytes], Iterable[tuple[str, int, bytes]]]


def craft(src: Path, dest: Path, edit: Edit, chunk_size: int = 1 << 20) -> Path:
    """``src``'s MCAP file(s) (a bag directory or a file) rewritten through ``edit`` into the
    file ``dest``."""
    files = sorted(src.glob("*.mcap")) if src.is_dir() else [src]
    with dest.open("wb") as out:
        w = Writer(out, chunk_size=chunk_size)
        w.start("ros2", "crafted")
        schemas: dict[str, int] = {}
        channels: dict[str, tuple[int, str]] = {}  # topic -> (channel id, schema name)
        for f in files:
            with f.open("rb") as stream:
                for schema, ch, msg in make_reader(stream).iter_messages(log_time_order=False):
                    assert schema is not None
                    if schema.name not in schemas:
                        schemas[schema.name] = w.register_schema(
                            schema.name, schema.encoding, schema.data
                        )
                    if ch.topic not in channels:
                        cid = w.register_channel(ch.topic, ch.message_encoding,
                                                 schemas[schema.name], ch.metadata)  # fmt: skip
                        channels[ch.topic] = (cid, schema.name)
                    for topic, t, data in edit(schema.name, ch.topic, msg.log_time, msg.data):
                        cid = channels[topic][0]
                        w.add_message(cid, log_time=t, data=data, publish_time=t)
        w.finish()
    return dest
