"""One board's clock probes, in the daemon: when the sync wants an exchange, send it; feed the
reply to the sync; hand the board the clock map while it samples on the grid.

Theory of operation
-------------------
The schedule is the sync's (``ClockSync.due``); this is the shell that runs it.  After a few
back-to-back exchanges on the session's thread (``first_estimate``: a map before the first
sample is published), probing moves to the thread that reads the board, as its *ticker*
(``BoardLink.set_ticker``): when a probe is due, the request is written with ``call_future`` and
the reply is handled by a callback on that same thread.  One probe is in flight at a time.

Why: on the daemon's shared I/O loop a probe then costs no thread hand-off at all (the loop
was awake anyway, or wakes once for the due time and once for the reply), where a blocking
call from the session's thread cost three wake-ups (measured: ~35 µs of CPU each here, and
with 64 boards the hand-offs were a fifth of the daemon's CPU).  t1 is taken right before the
request's write and t4 right after the read that brought the reply, as before; the reply is
never read late, since the loop does not gather while a call waits.

With many boards the probes are rationed (``probe_budget`` exchanges per second for all boards
together, default 100): a tracking board probes at most every ``boards / probe_budget`` s, so
the sync's CPU stays bounded as boards are added (each exchange costs a write that wakes the
board, a read and an estimator fit: ~0.2 ms of CPU here).  The bound stays honest: it widens
with the time since the last exchange.  Bursts after a connect, a reset or a surprise are not
rationed (recovery first).

A probe that times out is reported lost (the sync goes fast); its timeout is short when the
link's best round trip is known (``timeout_for``): a probe far slower than that is useless to
the estimator anyway, e.g. one that lands in a board's boot gap.
"""

from __future__ import annotations

import logging
import struct
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass

from ...errors import CallTimeout, FunctionFailed, LinkLost, MissingLinkError
from ...host.board import Board
from ...host.link import CallResult
from ...timesync.estimator import AddResult, Estimate
from ...timesync.exchange import Exchange
from ...timesync.sync import TRACKING, ClockSync

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ProbeContext:
    """What the prober needs of its session and daemon: values and callables."""

    name: str  #: the board's topic name (for log lines)
    timeout: float  #: s per call (the board spec's)
    link_timeout: float  #: s without a frame before the link is stale (the board spec's)
    byte_ns: float  #: ns per byte on a UART link (0: not a UART)
    realtime_offset_ns: int  #: CLOCK_REALTIME - CLOCK_MONOTONIC (host maps are in realtime)
    probe_gap: Callable[[], float]  #: s between a tracking board's probes (the daemon's budget)
    on_rtt: Callable[[float], None]  #: each exchange's round trip, µs
    on_error: Callable[[str], None]  #: a failure that is neither a timeout nor a lost link
    on_map_pushed: Callable[[], None]  #: the board took a clock map (a2jHostMap)
    #: each exchange and what the sync made of it (the session records it)
    on_exchange: Callable[[Exchange, AddResult], None] = lambda ex, result: None
    #: the board samples on the host-time grid: hand it the map after every exchange, not only
    #: once a second (board/timing.py)
    wants_map: Callable[[], bool] = lambda: False


class ClockProber:
    def __init__(self, ctx: ProbeContext, board: Board, sync: ClockSync) -> None:
        self.ctx = ctx
        self.board = board
        self.sync = sync
        self._in_flight = False
        self._asap = False  # a heartbeat asked for a probe now
        self._not_before = 0.0  # the daemon's probe budget: no tracking probe before this
        self._pushes = "a2jHostMap" in board.index

    # ---- on the session's thread --------------------------------------------------------------
    def first_estimate(self, exchanges: int = 8) -> None:
        """Back-to-back blocking exchanges: an estimate before any sample is mapped."""
        byte_ns = self.ctx.byte_ns
        for _ in range(exchanges):
            try:
                ex = self.board.clock_exchange(self.timeout_for(), byte_ns=byte_ns)
            except MissingLinkError as e:
                self._lost(e)
                continue
            self._exchanged(ex)
        if self._pushes:  # the board can act on host time from its first sample on
            try:
                self.push_map()
            except MissingLinkError as e:
                self._report(e)

    def start(self) -> None:
        """From now on, probe on the board's reading thread."""
        self.board.link.set_ticker(self.due, self.tick)

    def probe_now(self) -> None:
        """A probe as soon as none is in flight (a heartbeat: the link has been silent)."""
        self._asap = True
        self.board.link.reschedule()

    def push_map(self) -> None:
        """Hand the board the current clock map now (blocking; before a trigger)."""
        fut = self.push_map_future()
        if fut is not None:
            result = self.board.link.wait(fut, self.ctx.timeout)
            if result.code != 0:
                raise FunctionFailed(self.board.name, "a2jHostMap", result.code, result.payload)

    def push_map_future(self) -> Future[CallResult] | None:
        """Hand the board the current clock map, not waited for (the session's supervisor,
        before timed commands): the call's future, whose result says whether the board took
        it (counted when it did); None when there is no map yet."""
        fut = self._push()
        if fut is not None:
            fut.add_done_callback(self._map_counted)
        return fut

    def _push(self) -> Future[CallResult] | None:
        # The map is the estimate (the best guess of the truth), not the slewing published
        # map.  Once the board has taken it, it is the sync's ``given``: what the board's timed
        # calls act on (set in reply order on the reading thread, so an a2jAt answered after
        # it was converted with it).
        est = self.sync.estimate
        if est is None:
            return None
        payload = map_payload(est, self.ctx.realtime_offset_ns)
        fut = self.board.call_future("a2jHostMap", payload, timeout=self.ctx.timeout)
        sync = self.sync

        def took(f: Future[CallResult]) -> None:
            if f.exception() is None and f.result().code == 0:
                sync.given = est

        fut.add_done_callback(took)
        return fut

    def _map_counted(self, fut: Future[CallResult]) -> None:
        if fut.exception() is None and fut.result().code == 0:
            self.ctx.on_map_pushed()

    # ---- on the board's reading thread --------------------------------------------------------
    def due(self) -> float | None:
        if self._in_flight:
            return None
        if self._asap:
            return 0.0
        due = self.sync.due()
        if self.sync.state == TRACKING and due < self._not_before:
            return self._not_before  # bursts (connect, reset, surprise) are not limited
        return due

    def tick(self, now: float) -> None:
        if self._in_flight:
            return
        self._in_flight = True
        self._asap = False
        self._not_before = now + self.ctx.probe_gap()
        try:
            self.board.clock_exchange_async(
                self._on_reply, self.timeout_for(), byte_ns=self.ctx.byte_ns
            )
        except MissingLinkError as e:  # the link is gone; the session notices and reconnects
            self._in_flight = False
            self._lost(e)

    def _on_reply(self, got: Exchange | BaseException) -> None:
        self._in_flight = False
        if isinstance(got, BaseException):
            self._lost(got)
            return
        self._exchanged(got)
        # The map goes to the board after every exchange while something there samples on the
        # grid; otherwise only right before a timed command (push_map): a round trip a second
        # on every board costs the idle ones a third more CPU.
        if self._pushes and self.ctx.wants_map():
            try:
                fut = self._push()
            except MissingLinkError as e:
                self._report(e)
                return
            if fut is not None:
                fut.add_done_callback(self._map_pushed)

    def _map_pushed(self, fut: Future[CallResult]) -> None:
        try:
            result = fut.result()
        except MissingLinkError as e:
            self._report(e)
            return
        if result.code == 0:
            self.ctx.on_map_pushed()
        else:
            self.ctx.on_error(f"{self.ctx.name}: a2jHostMap returned {result.code}")

    # ---- both ---------------------------------------------------------------------------------
    def timeout_for(self) -> float:
        # A probe far slower than the link's best is lost anyway (useless to the estimator):
        # do not wait a whole call timeout for it, e.g. in a board's boot gap.
        t = self.ctx.timeout
        if self.sync.min_rtt_ns is not None:
            t = min(t, max(0.05, 20 * self.sync.min_rtt_ns / 1e9))
        return min(t, self.ctx.link_timeout / 3)

    def _exchanged(self, ex: Exchange) -> None:
        result = self.sync.on_exchange(ex, self.board.clock.monotonic())
        self.ctx.on_rtt(ex.rtt_ns / 1000)
        self.ctx.on_exchange(ex, result)
        if result is AddResult.RESET:
            log.warning(
                "%s: board clock went backwards: board reset, clock map restarted", self.ctx.name
            )

    def _lost(self, e: BaseException) -> None:
        self._report(e)
        self.sync.on_lost(self.board.clock.monotonic())

    def _report(self, e: BaseException) -> None:
        # A timeout is the sync's business; a lost link is the session's (it says why, e.g.
        # stale, and closing fails this call after that: it must not overwrite the reason).
        if not isinstance(e, (CallTimeout, LinkLost)):
            self.ctx.on_error(str(e))


def map_payload(est: Estimate, realtime_offset_ns: int) -> bytes:
    """``a2jHostMap``'s payload for an estimate: ``<Q board µs><q host ns><i rate - 1 in
    ppb>``, host times in CLOCK_REALTIME (the monotonic estimate plus the offset)."""
    ppb = round((est.rate / 1000.0 - 1.0) * 1e9)
    return struct.pack("<Qqi", est.b_ref, round(est.h_ref) + realtime_offset_ns, ppb)
