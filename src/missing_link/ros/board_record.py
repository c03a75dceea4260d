"""What a recording keeps of each board besides its topics, so that ``missing-link replay`` can
play the board back: its description (function table, properties, transducer descriptors), its
run-time configuration, and the board's own stamps of every sample.  Pure: records in, CDR
bytes out and back, checked against rosbags by the tests.

Three small message types of ours (any ROS 2 reader decodes them from the definition embedded
in the file: rosbags' AnyReader, the ``mcap`` reader with its ROS 2 decoder, Foxglove):

* ``/<board>/description`` (``BoardDescription``): when the board comes up, and at the start of
  every bag a recording rotates into;
* ``/<board>/config`` (``BoardConfig``): when the daemon has read the board's configuration,
  and after every change;
* ``/<board>/stamps`` (``BoardStamps``): the board stamps and SIF seqs of the samples recorded
  on its thesis-format topics, a batch per board whenever the recorder closes an MCAP chunk,
  written into the same chunk as the samples, so a file cut by SIGKILL keeps both or neither.

The thesis-format messages carry host times and values only, and stay exactly as they were.
A topic of these is ``/<board>/<kind>_record`` where a transducer is called ``<kind>``.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ..descriptors import Transducer

PACKAGE = "missing_link_msgs/msg/"
DESCRIPTION_TYPE = PACKAGE + "BoardDescription"
CONFIG_TYPE = PACKAGE + "BoardConfig"
STAMPS_TYPE = PACKAGE + "BoardStamps"

DESCRIPTION_MSG = """\
# A board as the daemon found it when it came up (missing-link replay serves it again).
string board              # its topic name
string url                # where the daemon reached it
string[] functions        # its function table, in index order (a2jGetMapping)
string[] property_keys    # its properties (a2jGetProperties), in the board's order
string[] property_values
string transds            # its transducer descriptors (transds/1 text)
string[] topics           # each transducer's topic, in descriptor order
"""
CONFIG_MSG = """\
# A board's run-time configuration (docs/configuration.md), when the daemon read it and after
# every change.
string board
string keys               # the key table (a2jConfigKeys: config/1 text)
string[] names            # every key, in table order
string[] values           # its value: true|false, a number, or an enum's choice
"""
STAMPS_MSG = """\
# The board's own stamps of the samples recorded on its topics since its previous BoardStamps,
# in recording order (missing-link replay).  Sample k is the next message recorded on
# topics[topic[k]]; its SIF's seq was seq[k]; its channels' board stamps (us) are the next
# channel-count entries of board_us; its hard clock bound (ns) was bound_ns[k] (-1: none), as
# its Update had it: the truth of its newest measured channel is within that of its host time.
string board
string[] topics
uint16[] topic
uint8[] seq
uint64[] board_us
int64[] bound_ns
"""
MESSAGES = {DESCRIPTION_TYPE: DESCRIPTION_MSG, CONFIG_TYPE: CONFIG_MSG, STAMPS_TYPE: STAMPS_MSG}
KINDS = ("description", "config", "stamps")


def record_topic(board: str, kind: str, transducers: Iterable[str]) -> str:
    """The topic of a board's ``kind`` record (``description``, ``config``, ``stamps``)."""
    return f"/{board}/{kind}_record" if kind in set(transducers) else f"/{board}/{kind}"


@dataclass(frozen=True)
class BoardDescription:
    board: str
    url: str
    functions: tuple[str, ...]
    properties: tuple[tuple[str, str], ...]
    transds: str
    topics: tuple[str, ...]

    @classmethod
    def of(
        cls,
        board: str,
        url: str,
        functions: Sequence[str],
        properties: Mapping[str, str],
        transducers: Sequence[Transducer],
        topics: Sequence[str],
    ) -> BoardDescription:
        """The description of a board that came up as ``board``: its descriptors as the board
        sent them, or as the host's descriptor file gave them (an original board)."""
        text = "transds/1\n" + "".join(t.line() + "\n" for t in transducers)
        return cls(board, url, tuple(functions), tuple(properties.items()), text, tuple(topics))

    @property
    def transducer_names(self) -> list[str]:
        names = []
        for line in self.transds.splitlines()[1:]:
            if line.strip() and not line.lstrip().startswith("#"):
                names.append(line.split(",", 1)[0].strip())
        return names


@dataclass(frozen=True)
class ConfigRecord:
    board: str
    keys: str
    names: tuple[str, ...]
    values: tuple[str, ...]


@dataclass(frozen=True)
class StampsRecord:
    board: str
    topics: tuple[str, ...]
    topic: tuple[int, ...]
    seq: tuple[int, ...]
    board_us: tuple[int, ...]
    #: per sample, its hard clock bound in ns (``Update.bound_ns``; -1: none); () in a
    #: recording made before it was kept
    bound_ns: tuple[int, ...] = ()


# ---- CDR (ROS 2, little endian; alignment counts from after the 4-byte header) -------------
class _Out:
    def __init__(self) -> None:
        self.parts: list[bytes] = [b"\x00\x01\x00\x00"]
        self.n = 0  # bytes after the header

    def _align(self, k: int) -> None:
        pad = -self.n % k
        if pad:
            self.parts.append(bytes(pad))
            self.n += pad

    def raw(self, data: bytes) -> None:
        self.parts.append(data)
        self.n += len(data)

    def u32(self, v: int) -> None:
        self._align(4)
        self.raw(struct.pack("<I", v))

    def string(self, s: str) -> None:
        data = s.encode("utf-8", "replace") + b"\0"
        self.u32(len(data))
        self.raw(data)

    def strings(self, items: Sequence[str]) -> None:
        self.u32(len(items))
        for s in items:
            self.string(s)

    def array(self, code: str, size: int, items: Sequence[int]) -> None:
        self.u32(len(items))
        if items:
            self._align(size)
            self.raw(struct.pack(f"<{len(items)}{code}", *items))

    def bytes(self) -> bytes:
        return b"".join(self.parts)


class _In:
    """Reads what ``_Out`` writes; a record that does not fit is a ValueError, never more."""

    def __init__(self, data: bytes) -> None:
        if len(data) < 4 or data[:2] != b"\x00\x01":
            raise ValueError("not little-endian CDR")
        self.data = memoryview(data)[4:]
        self.i = 0

    def _take(self, n: int, align: int = 1) -> memoryview:
        self.i += -self.i % align
        if n < 0 or self.i + n > len(self.data):
            raise ValueError("record shorter than it says")
        out = self.data[self.i : self.i + n]
        self.i += n
        return out

    def u32(self) -> int:
        value: int = struct.unpack("<I", self._take(4, 4))[0]
        return value

    def string(self) -> str:
        raw = bytes(self._take(self.u32()))
        if not raw.endswith(b"\0"):
            raise ValueError("string without its NUL")
        return raw[:-1].decode("utf-8", "replace")

    def strings(self) -> tuple[str, ...]:
        n = self.u32()
        if n > len(self.data):
            raise ValueError("string array longer than the record")
        return tuple(self.string() for _ in range(n))

    def more(self) -> bool:
        """Bytes left (a field a later version added)."""
        return self.i < len(self.data)

    def array(self, code: str, size: int) -> tuple[int, ...]:
        n = self.u32()
        if not n:
            return ()
        return struct.unpack(f"<{n}{code}", self._take(n * size, size))


def description_cdr(d: BoardDescription) -> bytes:
    out = _Out()
    out.string(d.board)
    out.string(d.url)
    out.strings(d.functions)
    out.strings([k for k, _ in d.properties])
    out.strings([v for _, v in d.properties])
    out.string(d.transds)
    out.strings(d.topics)
    return out.bytes()


def description_from_cdr(data: bytes) -> BoardDescription:
    r = _In(data)
    board, url, functions = r.string(), r.string(), r.strings()
    keys, values = r.strings(), r.strings()
    if len(keys) != len(values):
        raise ValueError("property keys and values differ in number")
    return BoardDescription(board, url, functions, tuple(zip(keys, values, strict=True)),
                            r.string(), r.strings())  # fmt: skip


def config_cdr(c: ConfigRecord) -> bytes:
    out = _Out()
    out.string(c.board)
    out.string(c.keys)
    out.strings(c.names)
    out.strings(c.values)
    return out.bytes()


def config_from_cdr(data: bytes) -> ConfigRecord:
    r = _In(data)
    board, keys, names, values = r.string(), r.string(), r.strings(), r.strings()
    if len(names) != len(values):
        raise ValueError("config names and values differ in number")
    return ConfigRecord(board, keys, names, values)


def stamps_cdr(s: StampsRecord) -> bytes:
    out = _Out()
    out.string(s.board)
    out.strings(s.topics)
    out.array("H", 2, s.topic)
    out.array("B", 1, s.seq)
    out.array("Q", 8, s.board_us)
    out.array("q", 8, s.bound_ns)
    return out.bytes()


def stamps_from_cdr(data: bytes) -> StampsRecord:
    r = _In(data)
    board, topics = r.string(), r.strings()
    topic, seq, board_us = r.array("H", 2), r.array("B", 1), r.array("Q", 8)
    bound_ns = r.array("q", 8) if r.more() else ()  # (none in older recordings)
    if len(topic) != len(seq) or any(i >= len(topics) for i in topic):
        raise ValueError("stamps that do not fit their topics")
    if bound_ns and len(bound_ns) != len(topic):
        raise ValueError("stamps whose bounds do not fit their samples")
    return StampsRecord(board, topics, topic, seq, board_us, bound_ns)


def stamps_size(board: str, topics: Iterable[str], samples: int, channels: int) -> int:
    """At most the bytes ``stamps_cdr`` gives for a batch of this size (the recorder keeps a
    chunk's stamps in that chunk: it reserves this much room)."""
    names = len(board.encode()) + sum(len(t.encode()) + 8 for t in topics)
    return 56 + names + 11 * samples + 8 * channels
