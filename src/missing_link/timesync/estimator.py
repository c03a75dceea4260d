"""The clock estimator: board time -> host time from ``a2jClock`` exchanges.  Pure code.

Theory of operation
-------------------
One exchange gives four stamps: ``t1`` host ns just before the request was written, ``t2`` board
µs when the request's last byte arrived, ``t3`` board µs just before the reply's first byte, and
``t4`` host ns when the reply had been read.  Causality alone gives two *hard* constraints on
the true map ``H`` (board µs -> host ns)::

    t1 + up_min   <= H(t2 + res)        the request was sent before it arrived
    H(t3)         <= t4 - down_min      the reply was sent before it was read

(``res``: the board tick, since a stamp is the tick *before* the event; ``up_min``/``down_min``:
delays known to be in every exchange: on a UART the request's bytes before its last one arrives,
the reply's bytes after t3.  Left out, the request's time on the wire shifts the band's middle by
half of it: 22 µs at 921,600 Bd, 217 µs at 115,200.)

Model: ``H(b) = h_ref + (b - b_ref) * 1000 * (1 + k)`` over a window of recent exchanges, in
residual coordinates ``r = host_us - board_us`` relative to the newest exchange, where the
lower constraints are points the line must pass above and the upper ones points it must pass
below (TICSync, Harrison & Newman 2011; linuxptp's linreg servo).

Each ``add``:
  1. sanity: ``t1 <= t4``, ``t2 <= t3``; a board time below the previous exchange's means the
     board clock restarted -> ``RESET`` (the caller starts over and flags a step);
  2. window: exchanges within ``window_s`` of board time; beyond ``max_points`` the one whose
     tighter constraint is loosest goes (the newest quarter always stays);
  3. skew by weighted least squares on the exchange midpoints, weights falling with the
     exchange's delay above the window's smallest (a slow exchange says little);
  4. hard skew range from pairs of constraints far apart in time; the skew is clamped into it.
     After a board reset, the same crystal's skew measured before it is a *prior*
     (``set_prior``), blended in with weights from the width of that hard range (a short
     window bounds the skew loosely, so the prior leads; a long one tightly, so the data does);
     its uncertainty grows with its age.  Measured on a real-process board: the burst right
     after a reset alone gave skews off by 1,000 ppm and more (errors of 300-500 µs for 1-3 s);
     with the prior, under 10 µs.  (No prior at the first connect: a guess of 0 ppm measured
     worse than the burst's own fit for crystals 150-200 ppm off);
  5. offset: the middle between the tightest lower and the tightest upper constraint at the
     fitted skew, each loosened by its age times the skew's sigma (plus the fit's lag, and half
     the curvature, under a rate that drifts by up to ``drift_per_s``: a linear fit of a
     drifting clock errs by both, so an old exchange must not win over a recent one); hard
     band at the newest exchange: every constraint, moved to ``b_ref`` along the fitted skew
     and widened by the skew uncertainty (plus an allowance for frequency wander over the
     window); the offset is clamped into the band;
  6. an empty band (the window no longer fits one line: the clock's rate wandered) drops the
     oldest exchanges until it fits again - this is what makes the window adaptive;
  7. the estimated error (statistical, next to the hard band; chrony's ``esterror`` next to its
     ``maxerror``): how well the offset is pinned, i.e. the gap between each side's tightest and
     next tightest constraint (``GAP_FACTOR`` times), or the scatter of the fastest exchanges'
     midpoints about the fitted line (a robust sigma) when that is less; an allowance for the
     asymmetry between the two directions that no round trip reveals (``ASYM_FRACTION`` of half
     the fastest round trip); the stamps' quantisation; and at a distance from ``b_ref`` the
     skew's sigma times that distance (``est_error_ns``).

The estimate carries the band, so any board time maps to host time with a hard interval that
widens with the distance from the newest exchange.  Everything is float µs relative to the
newest exchange, so the numbers stay small whatever the uptime.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from enum import Enum

import numpy as np

from .exchange import Exchange

#: The skew range assumed before two exchanges are far enough apart to bound it.  Ceramic
#: resonators are within ±0.5 %; crystals are far better.
MAX_SKEW = 5000e-6
#: A prior skew from before a board reset: its sigma when fresh, its growth per second of age
#: (a crystal's rate moves with temperature; 0.5 ppm/s is a fast change), and when it is dropped
PRIOR_SIGMA = 2e-6
PRIOR_WANDER = 0.5e-6
PRIOR_LIFE_S = 60.0
#: The estimated error allows for an asymmetry between the two directions of this fraction of
#: half the fastest round trip.  No round trip reveals an asymmetry, so it is calibrated against
#: board clocks whose truth is known: the one-way floors measured here differ by up to ~7 % of
#: the round trip over a pty (a process that slept longer wakes later), < 2 % over TCP with
#: kernel stamps at both ends (docs/timesync.md, "The estimated error").
ASYM_FRACTION = 0.12
#: The offset sits between each side's tightest constraint, which is off the path's floor by
#: about the gap to that side's next tightest (the last of a few draws from a delay tail);
#: this many such gaps (both sides, in quadrature, halved) make the offset's own sigma.
#: Calibrated on real processes over a pty (docs/timesync.md): where the fastest exchanges'
#: midpoints scatter by 15 µs with the VM's wake-ups, the tightest ones are within ~5 µs.
GAP_FACTOR = 1.5


class AddResult(Enum):
    ACCEPTED = "accepted"
    REJECTED = "rejected"  #: malformed stamps (t4 < t1 or t3 < t2); the estimate is unchanged
    RESET = "reset"  #: board time went backwards: the board restarted; call reset()


@dataclass(frozen=True)
class Estimate:
    """The fitted map at one moment, with its hard band."""

    b_ref: int  #: board µs of the newest exchange (t3)
    h_ref: float  #: host ns the map gives at b_ref
    rate: float  #: host ns per board µs (1000 * (1 + skew))
    lo_ns: float  #: hard band at b_ref, relative to h_ref (<= 0)
    hi_ns: float  #: (>= 0)
    dskew: float  #: hard skew uncertainty used to widen the band away from b_ref
    points: int  #: exchanges in the window
    span_s: float  #: board time the window covers
    min_delay_ns: float  #: the window's smallest exchange delay
    consistent: bool  #: False when even the smallest window violated a constraint
    #: the statistical error at ``b_ref``, squared (ns²): scatter, asymmetry allowance, ticks
    est_sq_ns: float = 0.0
    skew_sigma: float = 0.0  #: 1-sigma skew (dimensionless) for the error away from b_ref

    @property
    def skew(self) -> float:
        return self.rate / 1000.0 - 1.0

    @property
    def width_ns(self) -> float:
        return self.hi_ns - self.lo_ns

    def est_error_ns(self, board_us: int, deviation_ns: float = 0.0) -> float:
        """The statistical error (about one sigma) of host times mapped at ``board_us`` by a map
        ``deviation_ns`` away from this estimate (the published map's slew); never more than
        the hard bound there (a few wild exchanges right after connecting can scatter more)."""
        d = board_us - self.b_ref
        spread = self.skew_sigma * 1000.0 * d
        est = math.sqrt(self.est_sq_ns + spread * spread + deviation_ns * deviation_ns)
        hard = max(deviation_ns - self.lo_ns, self.hi_ns - deviation_ns)
        return min(est, hard + abs(d) * 1000.0 * self.dskew)

    def host_at(self, board_us: int) -> float:
        return self.h_ref + (board_us - self.b_ref) * self.rate

    def interval(self, board_us: int) -> tuple[float, float]:
        """Hard [lower, upper] host ns for board time ``board_us``."""
        d = board_us - self.b_ref
        centre = self.h_ref + d * self.rate
        widen = abs(d) * 1000.0 * self.dskew
        return centre + self.lo_ns - widen, centre + self.hi_ns + widen


class ClockEstimator:
    """Offset and skew of one board clock.  Feed ``add(Exchange)``; read ``estimate``."""

    def __init__(
        self,
        *,
        res_us: int = 1,
        window_s: float = 30.0,
        max_points: int = 128,
        min_points: int = 3,
        wander_per_s: float = 0.05e-6,
        floor_us: float = 1.0,
        memory_s: float = 5.0,
        drift_per_s: float = 0.5e-6,
    ) -> None:
        if max_points < min_points or min_points < 1:
            raise ValueError("need 1 <= min_points <= max_points")
        self.res_us = max(1, int(res_us))
        self.window_s = window_s
        self.max_points = max_points
        self.min_points = min_points
        self.wander_per_s = wander_per_s  #: assumed bound on how fast the rate can change
        self.floor_us = floor_us  #: delay noise floor in the weights (stamping jitter)
        self.memory_us = memory_s * 1e6  #: skew-fit weights fall by e every memory_s of age
        #: a rate drift the offset allows for (not a hard limit): a fast temperature ramp
        self.drift_per_us = drift_per_s / 1e6
        self.points: deque[Exchange] = deque()
        # The same window as rows (t1 + up_min, t2, t3, t4 - down_min) kept in step with ``points``:
        # the fit and the filter work on columns, without a Python pass over the exchanges.
        self._rows = np.empty((0, 4))
        self.estimate: Estimate | None = None
        self.accepted = 0
        self.rejected = 0
        self.trimmed = 0  #: exchanges dropped because the window stopped fitting one line
        self._prior: tuple[float, float] | None = None  # (skew, host ns when it was measured)

    def reset(self) -> None:
        self.points.clear()
        self._rows = np.empty((0, 4))
        self.estimate = None

    def set_prior(self, skew: float, host_ns: float) -> None:
        """The board's skew is known from before (its counter restarted, its crystal did not):
        lean on it until the window's own exchanges bound the skew better."""
        self._prior = (skew, host_ns)

    def _prior_skew(self, k: float, kmin: float, kmax: float, now_ns: float) -> float:
        """Blend the fitted skew ``k`` with the prior: inverse-variance weights, the fit's
        sigma taken as a quarter of the hard range [kmin, kmax] it must lie in."""
        assert self._prior is not None
        k0, at_ns = self._prior
        age_s = max(0.0, (now_ns - at_ns) / 1e9)
        if age_s > PRIOR_LIFE_S:  # the window is long by now, and the crystal may have moved
            self._prior = None
            return k
        var_p = (PRIOR_SIGMA + PRIOR_WANDER * age_s) ** 2
        var_f = ((kmax - kmin) / 4.0) ** 2
        return (k * var_p + k0 * var_f) / (var_p + var_f)

    def _drop_oldest(self) -> None:
        self.points.popleft()
        self._rows = self._rows[1:]

    def add(self, ex: Exchange) -> AddResult:
        if ex.t4 < ex.t1 or ex.t3 < ex.t2:
            self.rejected += 1
            return AddResult.REJECTED
        if self.points and ex.t2 < self.points[-1].t3:
            return AddResult.RESET
        self.points.append(ex)
        row = np.array([[ex.t1 + ex.up_min_ns, ex.t2, ex.t3, ex.t4 - ex.down_min_ns]], dtype=float)
        self._rows = np.concatenate((self._rows, row))
        self.accepted += 1
        while (
            len(self.points) > self.min_points and (ex.t3 - self.points[0].t2) > self.window_s * 1e6
        ):
            self._drop_oldest()
        if len(self.points) > self.max_points:
            self._evict()
        while True:
            est = self._fit()
            if est.consistent or len(self.points) <= self.min_points:
                break
            self._drop_oldest()
            self.trimmed += 1
        self.estimate = est
        return AddResult.ACCEPTED

    def _evict(self) -> None:
        """Drop the exchange that constrains least: the one whose tighter side is loosest
        against the current estimate (an NTP-style clock filter, per side).  The newest
        quarter is kept whatever its delays, so the window keeps reaching the present."""
        est = self.estimate
        if est is None:
            self._drop_oldest()
            return
        a = self._rows
        keep = len(a) - max(1, len(a) // 4)
        t1, t2, t3, t4 = a[:keep, 0], a[:keep, 1], a[:keep, 2], a[:keep, 3]
        lower = est.h_ref + (t2 + self.res_us - est.b_ref) * est.rate - t1
        upper = t4 - (est.h_ref + (t3 - est.b_ref) * est.rate)
        worst = int(np.argmax(np.minimum(lower, upper)))
        del self.points[worst]
        self._rows = np.delete(a, worst, axis=0)

    # ---- the fit -----------------------------------------------------------------------------
    def _fit(self) -> Estimate:
        """Steps 3-7 of the theory above on the window as it stands."""
        n = len(self.points)
        newest = self.points[-1]
        b_ref = newest.t3
        h_ref = (newest.t1 + newest.t4) / 2.0  # ns; only an origin
        res = float(self.res_us)
        a = self._rows
        t1, t2, t3, t4 = a[:, 0], a[:, 1], a[:, 2], a[:, 3]
        # residual coordinates: x = board µs - b_ref, r = (host - h_ref)/1000 - x
        xl = t2 + res - b_ref
        rl = (t1 - h_ref) / 1000.0 - xl
        xu = t3 - b_ref
        ru = (t4 - h_ref) / 1000.0 - xu
        xm = (t2 + t3) / 2.0 - b_ref
        rm = ((t1 + t4) / 2.0 - h_ref) / 1000.0 - xm
        delay = (t4 - t1) / 1000.0 - (t3 - t2)
        dmin = float(delay.min())
        kmin, kmax = _skew_range(xl, rl, xu, ru, n)
        consistent = kmin <= kmax
        k = self._skew(xm, rm, delay, dmin, kmin, kmax, float(t4[-1]))
        span_s = (t3.max() - t2.min()) / 1e6
        dk = (max(kmax - k, k - kmin) if consistent else 0.0) + self.wander_per_s * span_s
        # each constraint moved to b_ref along the fitted skew, and its distance from b_ref
        at_l, at_u, ax_l, ax_u = rl - k * xl, ru - k * xu, np.abs(xl), np.abs(xu)
        lo = float((at_l - dk * ax_l).max())
        hi = float((at_u + dk * ax_u).min())
        # Offset: the middle between each side's tightest constraint.  Each side is set by its
        # own tightest exchanges, so a link whose two directions are slow at different times
        # (a host busy with samples when the reply arrives) does not bias it, as a midpoint
        # fit of whole exchanges would.  "Tightest" counts the skew's uncertainty (its sigma,
        # taken as a quarter of the hard range, as for the prior) times the exchange's age, as
        # NTP's dispersion does: an old exchange that is tight only under the fitted skew does
        # not win over a recent one almost as tight.  Replayed on 12 recorded pty runs: p50
        # 8.0/7.3 -> 5.8/6.3 µs, worst max 25.8/28.4 -> 17.0/21.3 µs; simulated USB and FTDI
        # worst max 233/281 -> 158/231 µs.
        # Under a drifting rate the fitted skew lags by about the drift times half the fit's
        # memory, and a line misses the curve by half the drift times the age squared: both
        # count against an old exchange too.  Replayed on 12 recorded runs (6 pty, 6 TCP;
        # drifts up to 0.5 ppm/s): TCP p99 6.5 -> 3.4 µs, the pty unchanged.
        drift = self.drift_per_us
        sk = ((kmax - kmin) / 4.0 if consistent else 0.0) + drift * self.memory_us / 2.0
        side_l = at_l - (sk + 0.5 * drift * ax_l) * ax_l  # each constraint, loosened by its age
        side_u = at_u + (sk + 0.5 * drift * ax_u) * ax_u
        c = (float(side_l.max()) + float(side_u.min())) / 2.0
        if lo > hi:
            consistent = False
            c = (lo + hi) / 2.0
            lo = hi = c
        else:
            c = min(max(c, lo), hi)
        scatter = _scatter(rm - (c + k * xm), delay, side_l, side_u, n)
        asym = ASYM_FRACTION * dmin / 2.0
        return Estimate(
            b_ref=int(b_ref),
            h_ref=h_ref + c * 1000.0,
            rate=1000.0 * (1.0 + k),
            lo_ns=(lo - c) * 1000.0,
            hi_ns=(hi - c) * 1000.0,
            dskew=dk,
            points=n,
            span_s=span_s,
            min_delay_ns=dmin * 1000.0,
            consistent=consistent,
            est_sq_ns=(scatter**2 + asym**2 + res * res / 12.0) * 1e6,
            skew_sigma=sk,
        )

    def _skew(
        self,
        xm: np.ndarray,
        rm: np.ndarray,
        delay: np.ndarray,
        dmin: float,
        kmin: float,
        kmax: float,
        now_ns: float,
    ) -> float:
        """The skew: weighted least squares on the exchanges' midpoints (a slow exchange says
        little; a recent one more), blended with a prior, clamped into the hard range."""
        w = 1.0 / (self.floor_us**2 + (delay - dmin) ** 2)
        # A crystal's rate wanders (temperature): recent exchanges count more in the skew fit,
        # so it follows a drifting rate instead of averaging the whole window (measured: the
        # whole-run bench's ramps and bound misses came from that lag).
        w = w * np.exp(xm / self.memory_us)
        sw = float(w.sum())
        mx = float((w * xm).sum()) / sw
        mr = float((w * rm).sum()) / sw
        sxx = float((w * (xm - mx) ** 2).sum())
        prev = self.estimate
        if sxx > 0 and (xm.max() - xm.min()) > SKEW_SEP_US:
            k = float((w * (xm - mx) * (rm - mr)).sum()) / sxx
        else:
            k = prev.skew if prev is not None else 0.0
        if self._prior is not None:
            k = self._prior_skew(k, kmin, kmax, now_ns)
        if kmin <= kmax:
            k = min(max(k, kmin), kmax)
        return k


#: µs: exchanges closer than this bound the skew too loosely to matter
SKEW_SEP_US = 1000.0


def _skew_range(
    xl: np.ndarray, rl: np.ndarray, xu: np.ndarray, ru: np.ndarray, n: int
) -> tuple[float, float]:
    """The hard skew range from pairs of constraints (later upper vs earlier lower and v.v.):
    pairs of an older-half constraint with a newer-half one, the far-apart pairs that bound
    the skew tightly, at a quarter of the cost of all pairs (still hard bounds).  An empty
    range (kmin > kmax) means the window no longer fits one line."""
    kmin, kmax = -MAX_SKEW, MAX_SKEW
    h = max(1, n // 2)
    dx = xu[None, h:] - xl[:h, None]  # [i older lower, j newer upper]
    m = dx > SKEW_SEP_US
    if m.any():
        kmax = min(kmax, float(((ru[None, h:] - rl[:h, None])[m] / dx[m]).min()))
    dx2 = xl[None, h:] - xu[:h, None]  # [i older upper, j newer lower]
    m2 = dx2 > SKEW_SEP_US
    if m2.any():
        kmin = max(kmin, float(((rl[None, h:] - ru[:h, None])[m2] / dx2[m2]).max()))
    return kmin, kmax


def _scatter(
    off_line: np.ndarray, delay: np.ndarray, side_l: np.ndarray, side_u: np.ndarray, n: int
) -> float:
    """The offset's own sigma (µs): how well the two sides pin it (each side's tightest
    constraint against its next), or the fastest quarter's midpoints about the line (a robust
    sigma) if less.  ``off_line``: each exchange's midpoint minus the fitted line."""
    if n < 4:
        return 0.0
    fast = off_line[np.argsort(delay)[: max(4, n // 4)]]
    scatter = 1.4826 * float(np.median(np.abs(fast - np.median(fast))))
    low2 = np.partition(side_l, len(side_l) - 2)[-2:]  # the two tightest lower ones
    up2 = np.partition(side_u, 1)[:2]  # and upper ones
    gl, gu = float(low2.max() - low2.min()), float(up2.max() - up2.min())
    return min(scatter, GAP_FACTOR * math.sqrt(gl * gl + gu * gu) / 2.0)
