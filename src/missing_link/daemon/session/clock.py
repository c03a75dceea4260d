"""One board's clock synchronisation inside its session: the :class:`ClockSync`, the prober that
feeds it on the board's reading thread (``prober.py``), and the skew remembered across
connections of the same board (like ntpd's drift file, in memory).

At every connect ``start`` builds a new sync for the new link: a board that comes back with
the same ``board.serial`` gets its crystal's last skew as a prior; another board starts from
nothing; a board without ``a2jClock`` or ``getTime`` gets none (its samples keep their receive
times).  The session hands a :class:`ClockContext` of values and callables; this class never
sees the session.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Any

from ...host.board import Board
from ...host.link import CallResult
from ...ros.clock import ACCEPTED, REFUSED, RESET, record_of
from ...timesync.estimator import AddResult
from ...timesync.exchange import Exchange
from ...timesync.sync import ClockSync, SyncOptions
from .prober import ClockProber, ProbeContext


@dataclass(frozen=True)
class ClockContext:
    url: str
    timeout: float
    link_timeout: float
    byte_ns: float
    realtime_offset_ns: int
    probe_gap: Callable[[], float]
    record_clock: Callable[[str, Any], None]  #: (clock topic, ClockRecord) for recordings
    on_error: Callable[[Board, str], None]  #: a probe failed on this board's link
    on_rtt: Callable[[float], None]
    wants_map: Callable[[], bool]  #: something on the board is aligned: map after every exchange


class SessionClock:
    def __init__(self, ctx: ClockContext) -> None:
        self.ctx = ctx
        self.sync: ClockSync | None = None
        self.prober: ClockProber | None = None
        self.map_pushes = 0
        self._serial = ""  # board.serial of the board last connected
        self._skew_memory: tuple[str, float, float] | None = None  # (serial, skew, host ns)

    def start(self, board: Board, name: str, topic: str) -> str | None:
        """A new sync for ``board`` (named ``name``, its exchanges recorded on ``topic``);
        returns a warning when the board has no clock to synchronise."""
        old, self.sync, self.prober = self.sync, None, None
        serial = board.properties.get("board.serial", "")
        if old is not None and old.estimate is not None:
            # The same board again (a link outage): its crystal's skew is a prior, like
            # ntpd's drift file; a different board (another serial) starts from nothing.
            self._skew_memory = (self._serial, old.estimate.skew, old.estimate.h_ref)
        self._serial = serial
        if "a2jClock" not in board.index and "getTime" not in board.index:
            return "no a2jClock or getTime: host times are receive times, without a bound"
        res = int(board.properties.get("clock.res_us", "1"))  # range-checked by the handshake
        sync = ClockSync(SyncOptions(res_us=res), seed=hash(self.ctx.url) & 0xFFFF)
        memory = self._skew_memory
        if memory is not None and memory[0] == serial:
            sync.estimator.set_prior(memory[1], memory[2])
        sync.start(board.clock.monotonic())
        prober = ClockProber(self._probe_context(board, sync, name, topic), board, sync)
        prober.first_estimate()  # a map before any sample is published
        self.sync, self.prober = sync, prober
        prober.start()  # from now on on the board's reading thread (prober.py)
        return None

    def push_map(self) -> None:
        prober = self.prober
        if prober is not None:
            prober.push_map()

    def push_map_future(self) -> Future[CallResult] | None:
        """The map to the board, not waited for (None: no clock, or no map yet)."""
        prober = self.prober
        return prober.push_map_future() if prober is not None else None

    def _probe_context(self, board: Board, sync: ClockSync, name: str, topic: str) -> ProbeContext:
        ctx = self.ctx

        def on_map_pushed() -> None:
            self.map_pushes += 1

        results = {AddResult.ACCEPTED: ACCEPTED, AddResult.RESET: RESET}
        epoch = board.properties.get("clock.epoch", "")
        offset = ctx.realtime_offset_ns

        def on_exchange(ex: Exchange, result: AddResult) -> None:
            got = results.get(result, REFUSED)
            ctx.record_clock(topic, record_of(ex, got, sync.estimate, offset, epoch))

        return ProbeContext(
            name=name,
            timeout=ctx.timeout,
            link_timeout=ctx.link_timeout,
            byte_ns=ctx.byte_ns,
            realtime_offset_ns=offset,
            probe_gap=ctx.probe_gap,
            on_rtt=ctx.on_rtt,
            on_error=lambda text: ctx.on_error(board, text),
            on_map_pushed=on_map_pushed,
            on_exchange=on_exchange,
            wants_map=ctx.wants_map,
        )
