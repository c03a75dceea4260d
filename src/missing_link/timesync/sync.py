"""One board's clock synchronisation: estimator + published map + probe schedule.  Pure code.

Theory of operation
-------------------
States::

    unsynced --first exchange--> burst --burst_count exchanges--> tracking
    tracking --timeout / exchange outside the predicted band--> fast --fast_count--> tracking
    any --board time went backwards in an exchange or a sample (reset)--> unsynced
        (the next estimate steps the map)

The shell asks ``due()`` when to probe next, runs an ``a2jClock`` exchange and reports it with
``on_exchange`` (or ``on_lost`` after a timeout).  Probing is fast on connect (``burst``); while
tracking, the probe rate adapts to what keeps the bound: the interval doubles towards
``interval`` while the band is near the best this link has given (``floor``: the narrowest band
at an exchange, relaxing slowly so a link that got slower is re-learnt) and will not grow by
more than a quarter before the next probe; it halves towards ``fast_interval`` while the band
is wider than that (a link with widely spread delays needs more exchanges to find the few fast
ones).  It goes fast at once when an exchange is lost, lands outside the band the estimate
predicted for it (the clock rate moved) or when three in a row take far longer than the link's
best (an RTT jump; at most every 10 s, so a loaded host does not probe faster the slower it
gets); a reset restarts the burst.  An absolute ``target_us`` is always good enough, so a
link whose floor is wide (TCP, a bridge's latency timer) still slows down.

Glitches are outliers, not resets.  One stamp (in a sample or an exchange) that lands more than
``glitch_us`` away from where the estimate puts the board clock -- a byte flip that passed the
8-bit checksum, a driver bug -- is refused and counted (``outliers``), and a probe is due at
once to confirm or refute it.  A reset needs consistent evidence: two exchanges in a row that
agree with each other but not with the map, or ``reset_confirm`` samples in a row stamped far
behind the newest mapped one and consistent with each other.  A sample is also refused when it
would map later than ``now + glitch_us`` (nothing is measured in the future).

``map_many(board_us)`` gives an update's host times (CLOCK_MONOTONIC ns), a hard bound, the
estimated (statistical) error next to it, and flags; it is the only call the sample path makes,
and it is cheap (``map`` is its one-stamp form).  ``now`` is always passed in.  In the daemon the
sample path and the prober (a ticker, ``BoardLink.set_ticker``) both run on the thread that reads
the board; a lock still makes ``map_many`` safe against an ``on_exchange`` from another thread
(this class does not know who calls it).
"""

from __future__ import annotations

import math
import random
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from .estimator import AddResult, ClockEstimator, Estimate
from .exchange import Exchange
from .published import PublishedMap

UNSYNCED, BURST, TRACKING, FAST = "unsynced", "burst", "tracking", "fast"

#: Update/sample flags
STEP = 1  #: the map stepped at this sample (first sample after start or a board reset)
NOT_SYNCED = 2  #: no estimate yet: the host time is not from the clock map, the bound is unknown
OUTLIER = 4  #: the board stamp was far from the map (a glitch): refused; host time = receive time
#: an aligned transducer's sample that is not on its host-time grid (board/timing.py): the board
#: had no valid clock map then (it ran free), or it does not align
OFF_GRID = 8


@dataclass
class SyncOptions:
    burst_interval: float = 0.02  #: s between probes right after connecting or a reset
    burst_count: int = 25  #: exchanges in the burst
    interval: float = 0.5  #: s between probes once tracking (reached by doubling)
    fast_interval: float = 0.05  #: s between probes after a loss or a surprise
    fast_count: int = 10
    target_us: float = 20.0  #: a bound under which probing may always slow down
    floor_slack: float = 1.5  #: slow down while the bound is within this factor of the floor
    floor_relax: float = 1.02  #: the floor widens by this factor per exchange (re-learning)
    rtt_jump: float = 4.0  #: 3 exchanges in a row this many times slower than the best: go fast
    rtt_cooldown_s: float = 10.0  #: ... at most this often
    window_s: float = 30.0
    max_points: int = 128
    res_us: int = 1
    tau_s: float = 0.5  #: the published map reaches a new estimate this long after it appears
    max_slew: float = 500e-6
    #: a sample stamped this far behind the newest one mapped: the board may have restarted
    reset_backstep_us: int = 1_000_000
    #: ... and this many such samples in a row, consistent with each other, prove it
    reset_confirm: int = 3
    #: a stamp this far from the map (in a sample: beyond now + this) is an outlier
    glitch_us: int = 1_000_000
    #: exchanges an estimate needs before samples are mapped with it (after a reset, samples
    #: meanwhile get their receive time, flagged NOT_SYNCED): one or two exchanges give an
    #: offset off by up to half a round trip, which the map then takes tau to slew away
    map_min_points: int = 4


@dataclass(frozen=True)
class Mapped:
    host_ns: int  #: CLOCK_MONOTONIC ns
    est_error_ns: int  #: statistical: the error's typical size, about one sigma (-1: unknown)
    bound_ns: int  #: hard: |host_ns - truth| <= bound_ns (-1: unknown)
    flags: int


class ClockSync:
    def __init__(self, options: SyncOptions | None = None, seed: int | None = None) -> None:
        self.opt = options or SyncOptions()
        # Probe times are dithered: a schedule locked to the link's own period (USB frames, a
        # bridge's latency timer) would see the same delays every time and learn nothing.
        self._rng = random.Random(seed)
        o = self.opt
        self.estimator = ClockEstimator(
            res_us=o.res_us, window_s=o.window_s, max_points=o.max_points
        )
        self._map = PublishedMap(max_slew=o.max_slew, tau_s=o.tau_s)
        self.state = UNSYNCED
        self._lock = threading.Lock()
        self._next = 0.0
        self._interval = o.burst_interval
        self._count = 0  # exchanges in the current state
        self._step_pending = False
        self.exchanges = 0
        self.lost = 0
        self.resets = 0
        self.surprises = 0
        self.outliers = 0
        self._far_ex: Exchange | None = None  # an exchange far from the map, awaiting a second
        self._suspects = 0  # samples in a row stamped far behind the newest mapped
        self._suspect_last = 0
        self.last_rtt_ns: int | None = None
        self.min_rtt_ns: int | None = None
        self.last_error_ns = 0.0  # published - estimate at the last steer
        self._floor_ns: float | None = None  # narrowest band half-width at an exchange
        self._slow_run = 0  # exchanges in a row far slower than the link's best
        self._last_jump = -math.inf
        self.started_at: float | None = None
        self.first_bound_at: float | None = None  # s after start when the bound fell below 1 ms
        #: the estimate the board last took as its map (a2jHostMap): what its timed calls and
        #: its grid act on, however the estimate moved since (set by the shell that pushed it)
        self.given: Estimate | None = None

    # ---- schedule ----------------------------------------------------------------------------
    def start(self, now: float) -> None:
        self.started_at = now
        self._enter(BURST if self.state == UNSYNCED else self.state, now)
        self._next = now

    def due(self) -> float:
        return self._next

    def _enter(self, state: str, now: float) -> None:
        self.state = state
        self._count = 0
        o = self.opt
        self._interval = {BURST: o.burst_interval, FAST: o.fast_interval}.get(
            state, min(o.fast_interval * 2, o.interval)
        )

    def _advance(self, now: float, ok: bool) -> None:
        o = self.opt
        self._count += 1
        good = self._bound_good(ok)
        if self.state in (BURST, FAST):
            done = o.burst_count if self.state == BURST else o.fast_count
            if self._count >= done:
                self._enter(TRACKING, now)
        elif good and ok and self._count % 4 == 0:
            self._interval = min(o.interval, self._interval * 2)  # within target: slow down
        elif not good:
            self._interval = max(o.fast_interval, self._interval / 2)  # a wide band: speed up
        self._next = now + self._interval * self._rng.uniform(0.75, 1.25)

    def _rtt_jumped(self, rtt: int, now: float) -> bool:
        # The link got slower: three round trips in a row far above its best.  One slow
        # exchange is the host being busy; and at most once per rtt_cooldown_s, or a loaded
        # host (many boards, one interpreter) would probe faster the slower it gets.
        best = self.min_rtt_ns or rtt
        self._slow_run = self._slow_run + 1 if rtt > self.opt.rtt_jump * best + 200_000 else 0
        if self._slow_run < 3 or now - self._last_jump < self.opt.rtt_cooldown_s:
            return False
        self._slow_run = 0
        self._last_jump = now
        return True

    def _bound_good(self, ok: bool) -> bool:
        # Is the band as narrow as this link allows, and will it stay so until the next probe?
        est = self.estimator.estimate
        if est is None:
            return False
        o = self.opt
        half = max(-est.lo_ns, est.hi_ns)
        if ok:
            floor = self._floor_ns
            self._floor_ns = half if floor is None else min(floor * o.floor_relax, half)
        floor = self._floor_ns if self._floor_ns is not None else half
        growth = 2.0 * self._interval * 1e9 * est.dskew  # widening if the interval doubles
        limit = max(o.target_us * 1000.0, o.floor_slack * floor)
        return half <= limit and growth <= 0.25 * max(half, o.target_us * 1000.0)

    # ---- input -------------------------------------------------------------------------------
    def on_exchange(self, ex: Exchange, now: float) -> AddResult:
        self.exchanges += 1
        prior = self.estimator.estimate
        if prior is not None and abs(ex.t2 - self._board_at(prior, ex.t1)) > self.opt.glitch_us:
            first = self._far_ex
            if first is None or not _consistent(first, ex):
                self._far_ex = ex  # one far exchange is a glitch until the next one agrees
                self.outliers += 1
                self._next = now
                return AddResult.REJECTED
        self._far_ex = None
        rtt = ex.rtt_ns
        self.last_rtt_ns = rtt
        if self.min_rtt_ns is None or rtt < self.min_rtt_ns:
            self.min_rtt_ns = rtt
        with self._lock:
            prior = self.estimator.estimate
            result = self.estimator.add(ex)
            if result is AddResult.RESET:
                self._reset_locked()
                result = self.estimator.add(ex)
                result = AddResult.RESET if result is AddResult.ACCEPTED else result
            est = self.estimator.estimate
            if est is not None and result is not AddResult.REJECTED:
                if not self._map.started or self._map.newest_mapped is None:
                    # Nothing mapped yet: start from the newest (best) estimate, not the
                    # burst's first and slowest exchange; and only once it has a few.
                    if est.points >= self.opt.map_min_points:
                        self._map.start(est)
                        self._step_pending = True
                else:
                    self.last_error_ns = self._map.steer(est)
        surprise = False
        if prior is not None and result is AddResult.ACCEPTED:
            _, hi2 = prior.interval(ex.t2 + self.opt.res_us)
            lo3, _ = prior.interval(ex.t3)
            # The exchange proves the truth lies outside the band predicted for it: the rate moved.
            surprise = ex.t1 + ex.up_min_ns > hi2 or ex.t4 - ex.down_min_ns < lo3
            if surprise:
                self.surprises += 1
        if (
            self.first_bound_at is None
            and est is not None
            and self.started_at is not None
            and est.width_ns / 2 < 1e6
        ):
            self.first_bound_at = now - self.started_at
        jump = self._rtt_jumped(rtt, now) if result is AddResult.ACCEPTED else False
        if result is AddResult.RESET:
            self._floor_ns = None
            self._enter(BURST, now)
        elif (surprise or jump) and self.state == TRACKING:
            self._enter(FAST, now)
        elif self.state == UNSYNCED:
            self._enter(BURST, now)
        self._advance(now, result is AddResult.ACCEPTED)
        return result

    def on_lost(self, now: float) -> None:
        self.lost += 1
        if self.state == TRACKING:
            self._enter(FAST, now)
        self._advance(now, False)

    @staticmethod
    def _board_at(est: Estimate, host_ns: float) -> float:
        return est.b_ref + (host_ns - est.h_ref) / est.rate

    def _reset_locked(self) -> None:
        self.resets += 1
        self._floor_ns = None
        self._suspects = 0
        self._far_ex = None
        prior = self.estimator.estimate
        self.estimator.reset()
        if prior is not None:  # the counter restarted, not the crystal: keep its skew
            self.estimator.set_prior(prior.skew, prior.h_ref)
        self._map = PublishedMap(max_slew=self.opt.max_slew, tau_s=self.opt.tau_s)
        self.given = None  # (a board that restarted has no map)
        self.state = UNSYNCED

    # ---- output ------------------------------------------------------------------------------
    @property
    def estimate(self) -> Estimate | None:
        return self.estimator.estimate

    def map(self, board_us: int) -> Mapped | None:
        """Host time of a sample's board stamp; None before the first estimate."""
        got = self.map_many((board_us,))
        if got is None:
            return None
        hosts, est_error, bound, flags = got
        return Mapped(hosts[0], est_error, bound, flags)

    def map_many(
        self, board_us: Sequence[int], now: float | None = None, offset_ns: int = 0
    ) -> tuple[list[int], int, int, int] | None:
        """Host ns (CLOCK_MONOTONIC, plus ``offset_ns``: the caller's realtime offset, added
        here rather than in another pass) for each stamp of one update, plus the estimated
        error, the hard bound (both for the newest stamp) and flags; None before the first
        estimate.  ``now``: the host's receive time (monotonic s), to refuse stamps from the
        future.

        An outlier gives ``([], -1, -1, OUTLIER)``: the caller uses its receive time, flagged.
        ``reset_confirm`` updates in a row stamped more than ``reset_backstep_us`` behind the
        newest one mapped (and consistent with each other) mean the board restarted without the
        link dropping: the sync restarts (``resets`` counts it) and this update gets None, like
        every one until the next estimate.  The sample path: one lock, one segment lookup."""
        newest = max(board_us)
        o = self.opt
        with self._lock:
            est = self.estimator.estimate
            pm = self._map
            if est is None or not pm.started:
                return None
            seg = pm.segment(newest)
            h = seg[3] + (newest - seg[2]) * seg[4]  # pm.at(newest), unrounded: checks, bound
            last = pm.newest_mapped
            if last is not None and newest < last - o.reset_backstep_us:
                consistent = self._suspects and 0 <= newest - self._suspect_last <= o.glitch_us
                self._suspects = self._suspects + 1 if consistent else 1
                self._suspect_last = newest
                reset = self._suspects >= o.reset_confirm
                if reset:
                    self._reset_locked()
            elif now is not None and h > now * 1e9 + o.glitch_us * 1000:
                reset = False
            else:
                self._suspects = 0
                if last is None or newest > last:
                    pm.newest_mapped = newest
                hosts = pm.at_many(board_us, min(board_us), seg, offset_ns)
                flags = 0
                if self._step_pending:
                    flags = STEP
                    self._step_pending = False
                # The hard band at the newest stamp and the estimated error there, no more
                # than the band (est.interval and est.est_error_ns, inlined: this runs per
                # update), with how far the published map is from the estimate.
                d = newest - est.b_ref
                dev = h - (est.h_ref + d * est.rate)
                hard = max(dev - est.lo_ns, est.hi_ns - dev) + abs(d) * 1000.0 * est.dskew
                spread = est.skew_sigma * 1000.0 * d
                e = math.sqrt(est.est_sq_ns + spread * spread + dev * dev)
                return hosts, round(min(e, hard)), math.ceil(hard), flags
        # a reset, or an outlier: probe at once to confirm or refute
        if reset:
            self._enter(BURST, now or 0.0)
        else:
            self.outliers += 1
        self._next = now or 0.0
        return None if reset else ([], -1, -1, OUTLIER)

    def given_bound_ns(self, board_us: int) -> int | None:
        """How far from the host time the map the board was given (``given``) puts
        ``board_us`` the truth may lie: that map's hard band there, plus one board µs (the
        board acts at the tick at or before the asked time).  A timed call due at ``board_us``
        acts this close to its asked time; the estimate may have moved since the map was
        given, so the published bound does not cover it.  None: no map given."""
        est = self.given
        if est is None:
            return None
        lo, hi = est.interval(board_us)
        centre = est.host_at(board_us)
        return math.ceil(max(centre - lo, hi - centre) + est.rate)

    def status(self) -> dict[str, Any]:
        est = self.estimator.estimate
        out: dict[str, Any] = {
            "sync_state": self.state,
            "sync_exchanges": self.exchanges,
            "sync_lost": self.lost,
            "sync_resets": self.resets,
            "sync_surprises": self.surprises,
            "sync_outliers": self.outliers,
            "sync_interval_ms": round(self._interval * 1000, 1),
            "sync_floor_us": None if self._floor_ns is None else round(self._floor_ns / 1000, 2),
            "sync_rtt_us": None if self.last_rtt_ns is None else round(self.last_rtt_ns / 1000, 1),
            "sync_min_rtt_us": None
            if self.min_rtt_ns is None
            else round(self.min_rtt_ns / 1000, 1),
        }
        if est is not None:
            out.update(
                {
                    # host µs minus board µs, now
                    "offset_us": round(est.h_ref / 1000 - est.b_ref, 3),
                    # the board clock's rate error (a board running fast has a positive skew)
                    "skew_ppm": round((1000.0 / est.rate - 1.0) * 1e6, 3),
                    "bound_us": round(max(-est.lo_ns, est.hi_ns) / 1000, 2),
                    "est_error_us": round(est.est_error_ns(est.b_ref) / 1000, 2),
                    "slew_error_us": round(self.last_error_ns / 1000, 2),
                    "window_points": est.points,
                    "window_s": round(est.span_s, 1),
                }
            )
        if self.first_bound_at is not None:
            out["first_bound_ms"] = round(self.first_bound_at * 1000, 1)
        return out


def _consistent(a: Exchange, b: Exchange) -> bool:
    """Do two exchanges agree with each other: board time between them as host time passed
    (within 1 ms, plus 1000 ppm of it)?"""
    board = b.t2 - a.t3
    host_us = (b.t4 - a.t1) / 1000.0
    return 0 <= board <= host_us * 1.001 + 1000
