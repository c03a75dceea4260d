"""What the MCAP recorder keeps for ``missing-link replay`` (``ros/board_record.py``): per board
its description (when it comes up, and again at the start of every bag), its configuration (when
read, and after every change), the board stamps of its samples, and the actuator commands the
daemon took (``/<board>/<actuator>/cmd``, the actuator's own type).  The recorder's writer thread
owns one :class:`ReplayRecords`; nothing here writes a file: it turns what the daemon said into
(topic, CDR) for the writer.

Stamps are batched per board (topic index, SIF seq, each channel's board stamp) until the
writer closes a chunk; ``pending_bytes`` is at most what the batches will take, so the writer
can keep a chunk's stamps in that chunk (mcap.py)."""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from typing import Any

from ..host.config import ConfigKey, Value
from ..ros.board_record import (
    CONFIG_TYPE,
    DESCRIPTION_TYPE,
    STAMPS_TYPE,
    BoardDescription,
    ConfigRecord,
    StampsRecord,
    config_cdr,
    description_cdr,
    record_topic,
    stamps_cdr,
    stamps_size,
)
from ..topics import Command, Topic, Update


def value_text(v: Value) -> str:
    """A configuration value as the record keeps it."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v) if math.isfinite(v) else str(v)
    return str(v)


def _num(v: float | None) -> str:
    assert v is not None
    return repr(v) if v != int(v) else str(int(v))


def keys_text(keys: Sequence[ConfigKey]) -> str:
    """The key table as the board sent it (``a2jConfigKeys``: config/1 lines)."""
    lines = ["config/1"]
    for k in keys:
        if k.kind == "enum":
            default = next((c for c in k.choices if c == str(k.default)), str(k.default))
            limits = "|".join(k.choices)
        elif k.kind == "bool":
            default, limits = ("1" if k.default else "0"), ""
        else:
            default, limits = _num(float(k.default)), f"{_num(k.lo)}..{_num(k.hi)}"
        lines.append(f"{k.name};{k.kind};{default};{limits};{'ro' if k.read_only else ''}")
    return "\n".join(lines) + "\n"


def command_values(value: Any, now_ns: int) -> tuple[list[Any], int]:
    """A command as a face handed it (daemon/session/actuators.py takes the same forms) -> (the
    values, the first is the command; the host time it is for: its ``at_ns``, else ``now_ns``)."""
    at = now_ns
    if isinstance(value, Command):
        at = value.at_ns if value.at_ns is not None else now_ns
        value = value.values
    if isinstance(value, Update):
        value = [v for v in value.values if v is not None][:1]
    if not isinstance(value, (list, tuple)):
        value = [value]
    return list(value), at


def command_cdr(topic: Topic, value: Any, now_ns: int) -> bytes | None:
    """An actuator command as the recorder keeps it: in the actuator's own (thesis) type, its
    ``times[0]`` when it was for, as a command message says it (topics.py, ``Command``); None
    when our encoder cannot carry the value (the daemon took it: a bug, counted as dropped)."""
    assert topic.encoder is not None
    values, at = command_values(value, now_ns)
    n = topic.transducer.chan_count
    values = (values + [None] * n)[:n]
    try:
        return topic.encoder.encode([at] + [0] * (n - 1), values)
    except (struct.error, TypeError, OverflowError):
        return None


_INT64_MAX = (1 << 63) - 1


class _Batch:
    def __init__(self) -> None:
        self.topics: dict[str, int] = {}
        self.topic: list[int] = []
        self.seq: list[int] = []
        self.board_us: list[int] = []
        self.bound_ns: list[int] = []


class ReplayRecords:
    def __init__(self) -> None:
        self.descriptions: dict[str, BoardDescription] = {}
        self._keys: dict[str, list[ConfigKey]] = {}
        self._values: dict[str, dict[str, Value]] = {}
        self._names: dict[str, set[str]] = {}  # board -> its transducers' names
        self._batches: dict[str, _Batch] = {}
        self.pending_bytes = 0  #: at most what take_stamps() will hand over, in bytes

    def topic(self, board: str, kind: str) -> str:
        return record_topic(board, kind, self._names.get(board, ()))

    # ---- description and configuration ---------------------------------------------------------
    def describe(self, d: BoardDescription) -> tuple[str, str, bytes]:
        self.descriptions[d.board] = d
        self._names[d.board] = set(d.transducer_names)
        return self.topic(d.board, "description"), DESCRIPTION_TYPE, description_cdr(d)

    def config(
        self, board: str, keys: list[ConfigKey] | None, values: dict[str, Value]
    ) -> tuple[str, str, bytes] | None:
        """The configuration record after the daemon read it (``keys``) or after a change
        (``keys`` None): None until the keys are known."""
        if keys is not None:
            self._keys[board] = list(keys)
        self._values[board] = dict(values)
        return self._config(board)

    def _config(self, board: str) -> tuple[str, str, bytes] | None:
        keys = self._keys.get(board)
        if keys is None:
            return None
        values = self._values.get(board, {})
        names = tuple(k.name for k in keys)
        texts = tuple(value_text(values.get(k.name, k.default)) for k in keys)
        record = ConfigRecord(board, keys_text(keys), names, texts)
        return self.topic(board, "config"), CONFIG_TYPE, config_cdr(record)

    def again(self) -> list[tuple[str, str, bytes]]:
        """Every board's description and configuration, for a new bag (each bag replays alone)."""
        out = [self.describe(d) for d in list(self.descriptions.values())]
        for board in self._keys:
            rec = self._config(board)
            if rec is not None:
                out.append(rec)
        return out

    # ---- stamps ---------------------------------------------------------------------------------
    def sample(self, topic: Topic, seq: int, board_us: list[int], bound_ns: int = -1) -> None:
        board = topic.board
        batch = self._batches.get(board)
        if batch is None:
            batch = self._batches[board] = _Batch()
            self._names.setdefault(board, set())
            self.pending_bytes += stamps_size(board, (), 0, 0)
        index = batch.topics.get(topic.name)
        if index is None:
            index = batch.topics[topic.name] = len(batch.topics)
            self._names[board].add(topic.transducer.name)
            self.pending_bytes += len(topic.name.encode()) + 8
        batch.topic.append(index)
        batch.seq.append(seq & 0xFF)
        batch.board_us.extend(board_us)
        # (int64 in the record: a bound not an int of that range is packed as none or the most)
        ok = isinstance(bound_ns, int) and bound_ns >= -1
        batch.bound_ns.append(min(bound_ns, _INT64_MAX) if ok else -1)
        self.pending_bytes += 11 + 8 * len(board_us)

    def take_stamps(self) -> list[tuple[str, str, bytes]]:
        """The pending stamps, one record per board; pending is empty after it."""
        out = []
        for board, b in self._batches.items():
            record = StampsRecord(board, tuple(b.topics), tuple(b.topic), tuple(b.seq),
                                  tuple(b.board_us), tuple(b.bound_ns))  # fmt: skip
            out.append((self.topic(board, "stamps"), STAMPS_TYPE, stamps_cdr(record)))
        self._batches = {}
        self.pending_bytes = 0
        return out
