"""A recording read for ``missing-link replay``: per board what it was (description,
configuration, clock records) and, in a second pass, its samples as the SIFs it sent.

Both passes read the MCAP file(s) in file order with the streaming reader ``recover`` uses
(publishers/recover.py): every complete record, so a file cut by SIGKILL reads too, and a
damaged chunk costs only itself.  The file is input, not ours to trust: a record that does not
decode is counted and skipped, never raised past here; what makes a replay impossible (no
board description in it) is a :class:`RecordingError`, one line.

A sample is a thesis-format message (host times and values) paired with its entry in the
board's ``BoardStamps`` (board stamps and SIF seq, ros/board_record.py): the k-th entry for a
topic with the k-th message on it.  The recorder writes a chunk's stamps into that chunk, so
pairs are complete; samples left without stamps at the end (a recording made without them,
or cut inside a chunk) are counted (``unstamped``) and not replayed.
"""

from __future__ import annotations

import logging
import struct
import threading
from collections import Counter, deque
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from ..descriptors import Transducer, parse_transds
from ..errors import BoardError, DescriptorError, MissingLinkError
from ..host.config import parse_keys
from ..publishers.recover import MCAP_MAGIC, complete_messages
from ..ros.board_record import (
    CONFIG_TYPE,
    DESCRIPTION_TYPE,
    STAMPS_TYPE,
    BoardDescription,
    ConfigRecord,
    config_from_cdr,
    description_from_cdr,
    stamps_from_cdr,
)
from ..ros.clock import CLOCK_TYPE, clock_record_from_cdr, clock_topic
from ..ros.msgs import CdrEncoder
from .replay_clock import ClockKnots

log = logging.getLogger(__name__)


#: what the first pass keeps at most, whatever the file holds (more is counted as damaged):
#: boards (their descriptions, their clocks), and configuration changes per board (a day of
#: one every nine seconds)
MAX_BOARDS = 256
MAX_CONFIGS = 10_000


class RecordingError(MissingLinkError, ValueError):
    """A recording that cannot be replayed (the user's input): one line says why."""


@dataclass
class RecordedBoard:
    description: BoardDescription
    transducers: dict[str, Transducer]  #: thesis-format topic -> its transducer
    #: every configuration recorded, with its host time: the first, then each change
    configs: list[tuple[int, ConfigRecord]] = field(default_factory=list)
    clock: ClockKnots = field(default_factory=ClockKnots)  #: its clock records, as knots
    samples: int = 0  #: samples with board stamps
    first_ns: int | None = None  #: the recording's host time of its first sample
    last_ns: int = 0
    anchor: tuple[int, int] | None = None  #: (host ns, board µs) of its first stamped sample
    changed: bool = False  #: it came up again with other descriptors (the first are served)

    @property
    def name(self) -> str:
        return self.description.board

    @property
    def config(self) -> ConfigRecord | None:
        """The configuration the board had when the recording began."""
        return self.configs[0][1] if self.configs else None


@dataclass
class Recording:
    files: list[Path]
    boards: dict[str, RecordedBoard]
    damaged: int = 0  #: records that did not decode (skipped)
    skipped_chunks: int = 0
    #: the samples that may wait for their stamps, every board's second pass together
    waiting: Budget = field(default_factory=lambda: Budget(MAX_WAITING))


class Budget:
    """A count of places shared by threads (each board's feeder reads the file on its own)."""

    def __init__(self, places: int) -> None:
        self.places = places
        self.taken = 0
        self._lock = threading.Lock()

    def take(self) -> bool:
        """One place; False when none is left."""
        with self._lock:
            if self.taken >= self.places:
                return False
            self.taken += 1
            return True

    def give(self, n: int) -> None:
        with self._lock:
            self.taken -= n


@dataclass(frozen=True, slots=True)  # (20,000 wait per board: no __dict__ each)
class RecordedSif:
    log_ns: int  #: the recording's host time of the sample (its newest channel)
    transducer: Transducer
    board_us: tuple[int, ...]
    raw: tuple[Any, ...]  #: the values as the SIF carried them (N/A as the N/A value)
    seq: int


def mcap_files(paths: list[str]) -> list[Path]:
    """The MCAP files of bag directories or files, in the order given."""
    files: list[Path] = []
    for p in map(Path, paths):
        if not p.exists():
            raise FileNotFoundError(f"{p}: no such file or directory")
        found = sorted(p.glob("*.mcap")) if p.is_dir() else [p]
        if not found:
            raise RecordingError(f"{p}: no .mcap file in it")
        for f in found:
            with open(f, "rb") as stream:
                if stream.read(8) != MCAP_MAGIC:
                    raise RecordingError(f"{f}: not an MCAP file (no MCAP magic at its start)")
        files += found
    return files


def open_recording(paths: list[str]) -> Recording:
    """The first pass: every board's description, configuration, clock records and samples'
    span."""
    files = mcap_files(paths)
    rec = Recording(files, {})
    clocks: dict[str, ClockKnots] = {}
    spans: dict[str, tuple[int, int]] = {}
    skipped: Counter[str] = Counter()
    for schema, ch, msg in complete_messages(files, skipped):
        try:
            _first_pass(rec, schema.name, ch.topic, msg, clocks, spans)
        except (ValueError, struct.error, DescriptorError) as e:
            rec.damaged += 1
            log.debug("%s: a damaged record skipped: %s", ch.topic, e)
    rec.skipped_chunks = skipped["chunks"]
    if not rec.boards:
        raise RecordingError(
            f"{files[0]}: no board description in it (recorded before replay existed, or with "
            "[mcap] replay = false): nothing to replay"
        )
    for board in rec.boards.values():
        topic = clock_topic(board.name, set(board.description.transducer_names))
        board.clock = clocks.get(topic) or ClockKnots()
        got = [spans[t] for t in board.transducers if t in spans]
        if got:
            board.first_ns = min(a for a, _ in got)
            board.last_ns = max(b for _, b in got)
    return rec


def _first_pass(
    rec: Recording,
    kind: str,
    topic: str,
    msg: Any,
    clocks: dict[str, ClockKnots],
    spans: dict[str, tuple[int, int]],
) -> None:
    if kind == DESCRIPTION_TYPE:
        d = description_from_cdr(msg.data)
        known = rec.boards.get(d.board)
        if known is None and len(rec.boards) >= MAX_BOARDS:
            raise ValueError(f"a board more than {MAX_BOARDS}: {d.board[:40]!r}")
        if known is None:
            check_description(d)
            ts = parse_transds(d.transds, d.board)
            if len(ts) != len(d.topics):
                raise ValueError(f"{d.board}: {len(ts)} transducers, {len(d.topics)} topics")
            rec.boards[d.board] = RecordedBoard(d, dict(zip(d.topics, ts, strict=True)))
        elif (known.description.transds, known.description.topics) != (d.transds, d.topics):
            known.changed = True
    elif kind == CONFIG_TYPE:
        c = config_from_cdr(msg.data)
        board = rec.boards.get(c.board)
        if board is not None:
            check_config(c)  # (ValueError: a bad record, counted and skipped)
            if len(board.configs) >= MAX_CONFIGS:
                raise ValueError(f"{c.board}: a configuration change more than {MAX_CONFIGS}")
            if board.configs and board.configs[-1][1].keys == c.keys:  # (one key table, kept once)
                c = replace(c, keys=board.configs[-1][1].keys)
            board.configs.append((msg.log_time, c))
    elif kind == CLOCK_TYPE:
        if topic not in clocks and len(clocks) >= MAX_BOARDS:
            raise ValueError(f"a clock more than {MAX_BOARDS}: {topic[:60]!r}")
        clocks.setdefault(topic, ClockKnots()).add(clock_record_from_cdr(msg.data))
    elif kind == STAMPS_TYPE:
        s = stamps_from_cdr(msg.data)
        board = rec.boards.get(s.board)
        if board is not None:
            board.samples += len(s.topic)
            if board.anchor is None and s.board_us:
                board.anchor = (msg.log_time, s.board_us[0])
    else:
        lo, hi = spans.get(topic, (msg.log_time, msg.log_time))
        spans[topic] = (min(lo, msg.log_time), max(hi, msg.log_time))


def check_description(d: BoardDescription) -> None:
    """A recorded description is what a board could have said: its properties non-empty text
    without NUL (the board's own rule, board/runtime.py, which its replay is held to: a NUL in
    one ended ``replay`` before it served any board); ValueError otherwise."""
    for key, value in d.properties:
        if not key or "\0" in key or "\0" in value:
            raise ValueError(f"{d.board}: a property {key[:40]!r}: empty, or with a NUL")


def check_config(c: ConfigRecord) -> None:
    """A recorded configuration is what a board could have had: its key table parses (host/
    config.py's own checks) and every value is one its key takes (a whole number in range, a
    finite one, a choice: ``failsafe_ms = "1e400"`` ended a replay in a traceback, issue 43.8);
    ValueError naming the key otherwise."""
    try:
        table = {k.name: k for k in parse_keys(c.keys.encode(), c.board)}
    except BoardError as e:
        raise ValueError(str(e)) from None
    for name, text in zip(c.names, c.values, strict=True):
        key = table.get(name)
        if key is None:
            raise ValueError(f"{c.board}: a value for {name!r}, which its key table lacks")
        replace(key, read_only=False).parse(text)  # (ConfigError, a ValueError, if not)


@dataclass
class PairStats:
    sifs: int = 0
    unstamped: int = 0  #: samples without board stamps (not replayed)
    unmatched: int = 0  #: stamps without their sample
    damaged: int = 0
    held_max: int = 0  #: the most halves (samples, stamps) that waited at once


#: samples waiting for their stamps, every board's together (Recording.waiting): the recorder
#: writes the boards' stamps when it closes a chunk (1 MiB at most: fewer samples than this),
#: after the chunk's samples, so a chunk's samples wait at most; beyond this a board's oldest is
#: given up (counted), so memory is bounded whatever the file holds (samples whose stamps never
#: came were held whole: 7.8 MB made 202 MB, issue 43.10)
MAX_WAITING = 50_000


def recorded_sifs(rec: Recording, name: str, stats: PairStats) -> Iterator[RecordedSif]:
    """The second pass: board ``name``'s samples in the order it sent them, streamed.  A stamps
    record of the board stamps exactly the samples of it written since the one before (the
    recorder writes both on one thread: mcap.py), so there each topic's entries are paired with
    its waiting samples, the newest with the newest: samples left over before them lost their
    stamps (a damaged record), entries left over lost their samples; both are counted and
    dropped, and the pairs after are in step again."""
    board = rec.boards[name]
    decoders = {topic: CdrEncoder(t).struct for topic, t in board.transducers.items()}
    waiting: dict[str, deque[tuple[int, tuple[Any, ...]]]] = {t: deque() for t in decoders}
    budget, held = rec.waiting, 0
    try:
        for schema, ch, msg in complete_messages(rec.files):
            topic = ch.topic
            try:
                if topic in decoders:
                    n = board.transducers[topic].chan_count
                    waiting[topic].append((msg.log_time, decoders[topic].unpack(msg.data)[-n:]))
                    if budget.take():
                        held += 1
                        stats.held_max = max(stats.held_max, held)
                    else:  # (none left: the topic's oldest; its stamps, if they come, find it
                        waiting[topic].popleft()  # gone)
                        stats.unstamped += 1
                elif schema.name == STAMPS_TYPE:
                    s = stamps_from_cdr(msg.data)
                    if s.board != name:
                        continue
                    entries = _entries(s.topics, s.topic, s.seq, s.board_us, board)
                    before = sum(len(q) for q in waiting.values())
                    yield from _paired(entries, waiting, board, stats)
                    gone = before - sum(len(q) for q in waiting.values())
                    budget.give(gone)
                    held -= gone
            except (ValueError, struct.error) as e:
                stats.damaged += 1
                log.debug("%s: a damaged record skipped: %s", topic, e)
        stats.unstamped += held
    finally:
        budget.give(held)  # (a pass ended, or its reader stopped)


def _paired(
    entries: list[tuple[str, int, tuple[int, ...]]],
    waiting: dict[str, deque[tuple[int, tuple[Any, ...]]]],
    board: RecordedBoard,
    stats: PairStats,
) -> Iterator[RecordedSif]:
    """One stamps record's entries with the samples waiting for them (see recorded_sifs)."""
    wanted = Counter(topic for topic, _seq, _us in entries)
    for topic, q in waiting.items():
        extra = len(q) - wanted[topic]
        for _ in range(max(0, extra)):  # (older samples whose stamps were lost)
            q.popleft()
            stats.unstamped += 1
        wanted[topic] = max(0, -extra)  # (entries whose samples were lost: the oldest go)
    for topic, seq, us in entries:
        if wanted[topic]:
            wanted[topic] -= 1
            stats.unmatched += 1
            continue
        log_ns, raw = waiting[topic].popleft()
        stats.sifs += 1
        yield RecordedSif(log_ns, board.transducers[topic], us, raw, seq)


def _entries(
    topics: tuple[str, ...],
    index: tuple[int, ...],
    seqs: tuple[int, ...],
    board_us: tuple[int, ...],
    board: RecordedBoard,
) -> list[tuple[str, int, tuple[int, ...]]]:
    out = []
    at = 0
    for i, seq in zip(index, seqs, strict=True):
        t = board.transducers.get(topics[i])
        if t is None:
            raise ValueError(f"stamps for {topics[i]}, which is not a topic of {board.name}")
        n = t.chan_count
        if at + n > len(board_us):
            raise ValueError("stamps shorter than their samples' channels")
        out.append((topics[i], seq, board_us[at : at + n]))
        at += n
    return out
