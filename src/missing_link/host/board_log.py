"""A board's log on the host (docs/board-log.md): the log SIF (cmd ``LOG_CMD``, board/log.py)
decoded into a typed :class:`LogLine`, its fault kind named, its text cleaned; the board's
counts (``a2jLogInfo``) decoded into :class:`LogInfo`.  Pure: bytes in, records out.

A line's text is the board's (cleaned: ``text.safe_text``), with the name of the transducer it
is about in front (``tof: not answering at 0x29``); a fault the board says without a text is
named by its kind (``sonar: not answering``), and a line that only carries a count of dropped
lines says so.  A level the board sends that is not one of ROS's is taken up to the next one
(a board is untrusted; its line is not lost for it).  :class:`LogLines` gives ``Board`` its
``on_log``."""

from __future__ import annotations

import struct
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from ..board.log import HEAD, HEAD_LEN, LOG_CMD, SOURCE_BOARD
from ..text import safe_text

if TYPE_CHECKING:
    from ..descriptors import Transducer
    from ..j2a import SifReceived

__all__ = ["KINDS", "LEVELS", "LOG_CMD", "LogInfo", "LogLine", "LogLines", "parse_info"]

#: the levels of rcl_interfaces/msg/Log (and Python's logging: the same numbers)
LEVELS = {10: "DEBUG", 20: "INFO", 30: "WARN", 40: "ERROR", 50: "FATAL"}
#: the fault kinds of board/log.py, named
KINDS = {
    1: "not answering",
    2: "wrong part",
    3: "bus error",
    4: "timeout",
    5: "bad checksum",
    6: "overrun",
    7: "a call raised",
    8: "a driver's poll raised",
    9: "a timed call raised",
    10: "making safe raised",
    11: "storage failed",
    12: "a reply J2A cannot carry",
    13: "an error frame heard back",
}
TEXT_LIMIT = 300  #: characters of a line at most (the board sends at most 242 bytes)


def kind_name(kind: int) -> str:
    return "" if kind == 0 else KINDS.get(kind, f"fault kind {kind}")


def level_of(byte: int) -> int:
    """A board's level byte as a ROS level: the next one up (a board is untrusted)."""
    for level in LEVELS:
        if byte <= level:
            return level
    return 50


@dataclass(frozen=True)
class LogLine:
    """One line of a board's log."""

    board: str  #: the board's name (in the daemon: its topic token)
    level: int  #: DEBUG 10, INFO 20, WARN 30, ERROR 40 (rcl_interfaces/msg/Log's numbers)
    text: str  #: cleaned, the transducer's name in front when it is about one
    source: str = ""  #: the transducer it is about ("": the board itself)
    kind: str = ""  #: the fault's kind, named ("": a line, not a fault)
    board_us: int = 0  #: when the board said it (its clock)
    host_ns: int = 0  #: the same moment as a host time (CLOCK_REALTIME ns)
    dropped: int = 0  #: lines the board's budget dropped before this one
    #: a fault the board said before this host was there: known from its counts (a2jLogInfo)
    earlier: bool = False

    def __post_init__(self) -> None:
        # every line is text, whoever made it (the board's own are composed clean; the
        # daemon's about a board, such as an update refused, quote what the board said)
        for name in ("text", "source", "kind"):
            value = getattr(self, name)
            if not value.isprintable():
                object.__setattr__(self, name, safe_text(value, TEXT_LIMIT))

    @property
    def level_name(self) -> str:
        return LEVELS.get(self.level, str(self.level))


def compose(source: str, kind: int, text: str, dropped: int) -> str:
    """The line as a reader sees it (see the module's docstring)."""
    said = text or kind_name(kind)
    if not said and dropped:
        said = f"{dropped} log line{'s' if dropped != 1 else ''} dropped on the board (its budget)"
    return safe_text(f"{source}: {said}" if source else said, TEXT_LIMIT)


def decode_line(payload: bytes) -> tuple[int, int, int, int, int, bytes]:
    """A log SIF's payload -> (board µs, level, source, kind, dropped, text bytes), as
    board/log.py's ``encode_line`` made it; ValueError when it is shorter than its head."""
    if len(payload) < HEAD_LEN:
        raise ValueError(f"a log line has a {HEAD_LEN}-byte head, got {len(payload)} bytes")
    stamp, level, source, kind, dropped = struct.unpack(HEAD, payload[:HEAD_LEN])
    return stamp, level, source, kind, dropped, bytes(payload[HEAD_LEN:])


def parse_line(
    payload: bytes, board: str, names: Mapping[int, str], host_ns: int
) -> tuple[LogLine, int, int]:
    """A log SIF's payload -> (the line, its source id, its kind); ValueError when it is too
    short.  ``names``: transducer id -> name; ``host_ns``: the host time it is given."""
    board_us, level, source_id, kind, dropped, raw = decode_line(payload)
    source = "" if source_id == SOURCE_BOARD else names.get(source_id, f"transducer {source_id}")
    text = compose(source, kind, raw.decode("utf-8", "replace"), dropped)
    line = LogLine(
        board, level_of(level), text, source, kind_name(kind), board_us, host_ns, dropped
    )
    return line, source_id, kind


@dataclass(frozen=True)
class LogInfo:
    """The board's own counts (``a2jLogInfo``)."""

    said: int  #: lines the board sent since boot
    dropped: int  #: lines its budget dropped since boot
    other: int  #: faults that found its table full (counted, never said)
    #: (source id, kind, count) of every fault it said, in the order it first saw them
    faults: tuple[tuple[int, int, int], ...] = field(default_factory=tuple)


INFO_HEAD = struct.calcsize("<IIIB")


def parse_info(payload: bytes) -> LogInfo:
    """``a2jLogInfo``'s reply; ValueError when it does not hold what its head says."""
    if len(payload) < INFO_HEAD:
        raise ValueError(f"a2jLogInfo: {len(payload)} bytes, expected at least {INFO_HEAD}")
    said, dropped, other, n = struct.unpack("<IIIB", payload[:INFO_HEAD])
    if len(payload) != INFO_HEAD + 6 * n:
        raise ValueError(
            f"a2jLogInfo: {n} faults take {INFO_HEAD + 6 * n} bytes, not {len(payload)}"
        )
    faults = tuple(struct.iter_unpack("<BBI", payload[INFO_HEAD:]))
    return LogInfo(said, dropped, other, faults)


class LogLines:
    """``Board.on_log``: a base of :class:`~missing_link.host.board.Board`, which has the rest."""

    bad_log_lines = 0  #: log SIFs too short to be a line (counted, dropped)
    transducers: list[Transducer] | None

    @property
    def name(self) -> str:
        raise NotImplementedError

    def on_sif(self, cmd: int | None, handler: Callable[[SifReceived, float], None]) -> None:
        raise NotImplementedError

    def on_log(self, callback: Callable[[LogLine], None]) -> None:
        """Call ``callback(line)`` for every line of the board's log (docs/board-log.md), on
        the thread that reads the board; its host time is when it arrived (the daemon maps the
        board's stamp with the clock sync instead).  A line too short to be one is counted in
        ``bad_log_lines`` and dropped."""

        def handler(sif: SifReceived, _now: float) -> None:
            names = {t.id: t.name for t in self.transducers or ()}
            try:
                line, _source, _kind = parse_line(sif.payload, self.name, names, time.time_ns())
            except ValueError:
                self.bad_log_lines += 1
                return
            callback(line)

        self.on_sif(LOG_CMD, handler)
