"""One board's log in the daemon (docs/board-log.md): its log SIFs in, :class:`LogLine` records out
to every publisher (``/rosout`` on the ROS faces, ``/<board>/log`` in recordings, the bus's log
subscribers, the web console), a console line ``[board] LEVEL text`` through the logging system,
and the counts the board's status shows.

Theory of operation
-------------------
The sample path hands every log SIF (cmd ``LOG_CMD``) here, on the board's reading thread.  A
line is decoded (``host/board_log.py``); its board stamp becomes a host time through the clock
sync's estimate (never after the line arrived; its arrival before the first estimate); it is
counted by level, the lines the board dropped before it (its ``dropped``) are added up, and it
goes to ``publish`` and to the logger ``missing_link.boards.<name>`` at its level (the root
filter of ``logs.py`` cleans and rate-limits what reaches the terminal).  A fault line (said
once on the board) is remembered by its source and kind.

At each handshake (``connect``) and once a diagnostics period (``refresh``, answered on the
reading thread) the board's own counts are read, where it has them (``a2jLogInfo``): every
fault it said and how often it happened since, the lines its budget dropped since boot.  A fault
it counts that this host never saw said (it happened before the host came: a sensor absent at
boot is said before anyone listens) is said now, once, from the counts (``earlier``): ERROR for
the kinds that are code that raised, WARN for the rest.  A board without ``a2jLogInfo`` (older
firmware, the 2014 board) is simply not asked; a reply that makes no sense is counted
(``log_info_errors``), never raised.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import replace
from typing import Any

from ...errors import MissingLinkError
from ...host.board import Board
from ...host.board_log import LogInfo, LogLine, compose, kind_name, parse_info, parse_line
from ...host.link import CallResult
from ...timesync.sync import ClockSync

log = logging.getLogger(__name__)

#: fault kinds said at ERROR (code that raised, a reply J2A cannot carry): board/log.py's
ERROR_KINDS = frozenset((7, 8, 9, 10, 12))
LEVEL_KEYS = {10: "log_debug", 20: "log_info", 30: "log_warn", 40: "log_error", 50: "log_error"}


class BoardLogPath:
    def __init__(self, publish: Callable[[LogLine], None], realtime_offset_ns: int) -> None:
        self.publish = publish
        self.realtime_offset_ns = realtime_offset_ns
        self.name = ""  #: the board's topic token (set by the session at each handshake)
        self.names: dict[int, str] = {}  #: transducer id -> name, as of the latest handshake
        self.sync: ClockSync | None = None
        self.by_level = dict.fromkeys(LEVEL_KEYS.values(), 0)
        self.carried_dropped = 0  #: lines the board dropped, as its lines said (since start)
        self.bad_lines = 0
        self.info_errors = 0
        self.info: LogInfo | None = None  #: the board's own counts, as last read
        self._said: set[tuple[int, int]] = set()  # (source, kind) said on this board boot
        self._early: set[tuple[int, int]] = set()  # ... of those, said from the counts
        self._epoch = ""
        self._lock = threading.Lock()
        self._asking = False

    # ---- lines ------------------------------------------------------------------------------
    def on_sif(self, payload: bytes, now_mono: float) -> None:
        arrived = int(now_mono * 1e9) + self.realtime_offset_ns
        try:
            line, source, kind = parse_line(payload, self.name, self.names, arrived)
        except ValueError:
            self.bad_lines += 1
            return
        host = self._host_ns(line.board_us, arrived)
        if host != arrived:
            line = replace(line, host_ns=host)
        if kind:
            key = (source, kind)
            with self._lock:
                if key in self._early:
                    self._early.discard(key)
                    return  # (said from the counts already, as the line was on its way)
                self._said.add(key)
        self.carried_dropped += line.dropped
        self._emit(line)

    def _host_ns(self, board_us: int, arrived: int) -> int:
        sync = self.sync
        est = sync.estimate if sync is not None else None
        if est is None:
            return arrived
        host = int(est.h_ref + (board_us - est.b_ref) * est.rate) + self.realtime_offset_ns
        return min(host, arrived)  # (said before it arrived, whatever the map's error)

    def _emit(self, line: LogLine) -> None:
        key = LEVEL_KEYS.get(line.level, "log_error")
        self.by_level[key] += 1
        # (formatted here: the log filter tells lines apart by their text, so one line never
        # holds back another)
        text = f"[{line.board}] {line.level_name} {line.text}"
        logging.getLogger(f"missing_link.boards.{line.board}").log(line.level, text)
        self.publish(line)

    # ---- the board's counts ------------------------------------------------------------------
    def connect(self, board: Board, epoch: str, timeout: float) -> None:
        """At a handshake (the supervisor's thread): a new board boot forgets what was said;
        the board's counts are read, and the faults said before this host came are said."""
        with self._lock:
            if epoch != self._epoch or not epoch:
                self._said.clear()
                self._early.clear()
                self._epoch = epoch
        if "a2jLogInfo" not in board.index:
            self.info = None
            return
        try:
            result = board.call("a2jLogInfo", timeout=timeout)
        except MissingLinkError as e:
            self.info_errors += 1
            log.debug("%s: a2jLogInfo: %s", self.name, e)
            return
        self._took(result)

    def refresh(self, board: Board, timeout: float) -> None:
        """Once a diagnostics period (the supervisor's thread): ask again, answered on the
        reading thread; one question at a time."""
        if "a2jLogInfo" not in board.index or self._asking:
            return
        try:
            fut = board.call_future("a2jLogInfo", timeout=timeout)
        except MissingLinkError:
            return  # (the link is going: the session says why)
        self._asking = True
        fut.add_done_callback(self._answered)

    def _answered(self, fut: Future[CallResult]) -> None:
        self._asking = False
        if fut.exception() is None:
            self._took(fut.result())

    def _took(self, result: CallResult) -> None:
        try:
            if result.code != 0:
                raise ValueError(f"a2jLogInfo answered {result.code}")
            info = parse_info(result.payload)
        except ValueError as e:
            self.info_errors += 1
            log.debug("%s: %s", self.name, e)
            return
        self.info = info
        for source, kind, count in info.faults:
            with self._lock:
                if (source, kind) in self._said:
                    continue
                self._said.add((source, kind))
                self._early.add((source, kind))
            name = self.names.get(source, "" if source == 0xFF else f"transducer {source}")
            text = compose(name, kind, "", 0) + f" (before this host was there; {count}x since)"
            level = 40 if kind in ERROR_KINDS else 30
            now = time.time_ns()  # (when the host learnt of it: the board's counts say no when)
            self._emit(LogLine(self.name, level, text, name, kind_name(kind), 0, now, 0, True))

    # ---- status ------------------------------------------------------------------------------
    def counters(self) -> dict[str, Any]:
        """For the board's status and ``/diagnostics``: lines by level, the lines the board
        dropped (its own count once read, else what its lines carried), its faults and how
        often each happened (``log_faults``)."""
        info = self.info
        faults = ""
        if info is not None:
            faults = "; ".join(f"{self._who(s)}{kind_name(k)} x{n}" for s, k, n in info.faults[:8])
            if len(info.faults) > 8:
                faults += f"; {len(info.faults) - 8} more"
            if info.other:
                faults += f"; {info.other} beyond the board's table"
        return {
            **self.by_level,
            "log_dropped": info.dropped if info is not None else self.carried_dropped,
            "log_faults": faults,
            "bad_log_lines": self.bad_lines,
            "log_info_errors": self.info_errors,
        }

    def _who(self, source: int) -> str:
        return "" if source == 0xFF else f"{self.names.get(source, f'transducer {source}')} "


__all__ = ["BoardLogPath"]
