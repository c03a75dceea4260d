"""Clock synchronisation: the pure estimator and the published map (the sync state machine:
test_timesync_sync.py; the board's stamps and the daemon end to end: test_timesync_board.py)."""

from __future__ import annotations

import math
import random
from collections.abc import Iterator

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from missing_link.timesync import (
    AddResult,
    ClockEstimator,
    Estimate,
    Exchange,
    PublishedMap,
)


def exchanges(offset_us: float, skew: float, seed: int, n: int, spacing_s: float = 0.05):
    """Exchanges against board µs = offset + (1 + skew) * host µs, random delays, 1 µs ticks."""
    rng = random.Random(seed)
    t = 1e12
    out = []
    for _ in range(n):
        t += spacing_s * 1e9 * rng.uniform(0.5, 1.5)
        up = rng.expovariate(1 / 20_000) + 5_000
        turn = rng.uniform(2_000, 30_000)
        down = rng.expovariate(1 / 20_000) + 5_000
        t2h = t + up
        t3h = t2h + turn
        t4 = t3h + down
        b = lambda h: math.floor(offset_us + (1 + skew) * h / 1000)  # noqa: E731
        out.append((Exchange(int(t), b(t2h), b(t3h), math.ceil(t4)), t2h, t3h))
    return out


def truth_ns(offset_us: float, skew: float, board_us: float) -> float:
    return (board_us - offset_us) / (1 + skew) * 1000


def test_uart_wire_time_is_a_known_delay_not_a_bias() -> None:
    """On a 115,200 Bd UART the request (5 bytes) is on the wire for 434 µs before t2 and the
    reply (21 bytes) for 1,823 µs after t3.  Told both, the estimate is centred on the truth;
    told only the reply's, it is off by half the request's time, inside a band that still holds
    the truth (hard either way)."""
    byte_ns = 10e9 / 115_200
    offset, skew = 5_000_000.0, 40e-6
    rng = random.Random(7)
    told, half_told = ClockEstimator(), ClockEstimator()
    t = 1e12
    for _ in range(200):
        t += 0.05e9 * rng.uniform(0.5, 1.5)
        t2h = t + 5 * byte_ns + rng.expovariate(1 / 20_000) + 3_000  # bytes, then the ISR
        t3h = t2h + rng.uniform(2_000, 30_000)
        t4 = t3h + 21 * byte_ns + rng.expovariate(1 / 20_000) + 3_000
        b = lambda h: math.floor(offset + (1 + skew) * h / 1000)  # noqa: E731
        t1, t2, t3 = int(t), b(t2h), b(t3h)
        told.add(Exchange(t1, t2, t3, math.ceil(t4), int(21 * byte_ns), int(5 * byte_ns)))
        half_told.add(Exchange(t1, t2, t3, math.ceil(t4), int(21 * byte_ns)))
    errors = []
    for est in (told, half_told):
        e = est.estimate
        assert e is not None and e.consistent
        err = e.host_at(e.b_ref) - truth_ns(offset, skew, e.b_ref)
        assert e.lo_ns - 1_100 <= err <= e.hi_ns + 1_100  # the truth is inside the hard band
        errors.append(err)
    assert abs(errors[0]) < 10_000
    assert abs(errors[1] - (-5 * byte_ns / 2)) < 10_000  # 217 µs early


# ---- estimator ---------------------------------------------------------------------------------
@settings(max_examples=40, deadline=None)
@given(
    offset=st.floats(-1e9, 1e9),
    skew_ppm=st.floats(-400, 400),
    seed=st.integers(0, 2**16),
    n=st.integers(1, 150),
)
def test_truth_is_always_inside_the_hard_band(
    offset: float, skew_ppm: float, seed: int, n: int
) -> None:
    skew = skew_ppm * 1e-6
    est = ClockEstimator()
    for ex, _, _ in exchanges(offset, skew, seed, n):
        assert est.add(ex) is AddResult.ACCEPTED
        e = est.estimate
        assert e is not None and e.consistent
        for b in (ex.t2, ex.t3, ex.t3 + 50_000):  # at the exchange and 50 ms beyond it
            lo, hi = e.interval(b)
            true = truth_ns(offset, skew, b)
            # the tick: board time b covers [b, b+1) µs of its own clock
            assert lo - 1_100 <= true <= hi + 1_100


def test_estimate_converges_on_offset_and_skew() -> None:
    offset, skew = 123_456_789.0, 87e-6
    est = ClockEstimator()
    for ex, _, _ in exchanges(offset, skew, 1, 400):
        est.add(ex)
    e = est.estimate
    assert e is not None
    assert abs(e.skew - (1 / (1 + skew) - 1)) < 1e-6  # the map's rate is the inverse
    err = e.host_at(e.b_ref) - truth_ns(offset, skew, e.b_ref)
    assert abs(err) < 5_000  # ns; delays are 5 µs + exp(20 µs) each way
    assert abs(err) <= max(-e.lo_ns, e.hi_ns)


def test_malformed_and_backwards_exchanges() -> None:
    est = ClockEstimator()
    assert est.add(Exchange(100, 10, 5, 200)) is AddResult.REJECTED  # t3 < t2
    assert est.add(Exchange(300, 10, 20, 200)) is AddResult.REJECTED  # t4 < t1
    assert est.estimate is None and est.rejected == 2
    assert est.add(Exchange(1_000_000, 500, 510, 1_050_000)) is AddResult.ACCEPTED
    assert est.add(Exchange(2_000_000, 400, 410, 2_050_000)) is AddResult.RESET  # clock went back
    assert est.estimate is not None and est.estimate.points == 1  # unchanged until reset()


def test_window_drops_exchanges_that_no_longer_fit_one_line() -> None:
    """A rate change (a temperature step) makes old exchanges inconsistent: they are trimmed,
    and the estimate follows the new rate."""
    h_step = 1e12 + 10e9  # host ns at which the board starts running 200 ppm fast

    def board(h: float) -> int:
        if h < h_step:
            return math.floor(h / 1000)
        return math.floor(h_step / 1000 + (h - h_step) * (1 + 200e-6) / 1000)

    rng = random.Random(9)
    est = ClockEstimator(window_s=1000)
    t = 1e12
    for _ in range(400):  # 20 s at 20 Hz, the step in the middle
        t += 50e6
        t2h = t + rng.expovariate(1 / 10_000) + 5_000
        t3h = t2h + 10_000
        est.add(
            Exchange(int(t), board(t2h), board(t3h), int(t3h + rng.expovariate(1 / 10_000) + 5_000))
        )
    assert est.trimmed > 0
    e = est.estimate
    assert e is not None and e.consistent
    assert e.span_s < 15  # the window no longer reaches back before the step
    assert abs(e.skew - (1 / (1 + 200e-6) - 1)) < 5e-6


# ---- published map -----------------------------------------------------------------------------
@settings(max_examples=50, deadline=None)
@given(seed=st.integers(0, 2**16))
def test_published_map_is_continuous_strictly_increasing_and_slew_limited(seed: int) -> None:
    rng = random.Random(seed)
    pm = PublishedMap(tau_s=0.5)
    est = ClockEstimator()
    b_prev, h_prev = None, None
    rates: list[float] = []  # the estimates' rates the segments between two samples can use
    for ex, _, _ in exchanges(rng.uniform(0, 1e9), rng.uniform(-3e-4, 3e-4), seed, 60):
        est.add(ex)
        e = est.estimate
        assert e is not None
        rates = [*rates[-2:], e.rate]
        # a jittery estimate: the map must absorb jumps of up to ±2 ms without stepping
        jumped = type(e)(**{**e.__dict__, "h_ref": e.h_ref + rng.uniform(-2e6, 2e6)})
        if not pm.started:
            pm.start(jumped)
        else:
            pm.steer(jumped)
        for b in sorted(rng.randrange(ex.t2 - 20_000, ex.t3 + 60_000) for _ in range(5)):
            if b_prev is not None and b <= b_prev:
                continue
            h = pm.map(b)
            if b_prev is not None:
                assert h > h_prev  # strictly increasing
                rate = (h - h_prev) / (b - b_prev)
                # no step hides here: within the slew limit (500 ppm, with a margin for
                # rounding) of the estimates whose segments lie between the two samples (early
                # estimates' skews differ by thousands of ppm, so "the newest" is not enough)
                assert min(rates) * (1 - 6e-4) < rate < max(rates) * (1 + 6e-4)
            b_prev, h_prev = b, h
    assert pm.steps == 1


def moving_estimates(count: int, skews: list[float]) -> Iterator[Estimate]:
    """``count`` estimates, each from its own 12 exchanges, the k-th with the offset 1 ms * k
    and the skew ``skews[k % len(skews)]``: a map steered by them has a segment per steer."""
    for k in range(count):
        est = ClockEstimator()
        for ex, _, _ in exchanges(1000.0 * k, skews[k % len(skews)], k, 12, spacing_s=0.1):
            est.add(ex)
        assert est.estimate is not None
        yield est.estimate


@settings(max_examples=50, deadline=None)
@given(st.lists(st.integers(0, 3_000_000), min_size=1, max_size=16), st.integers(0, 5))
def test_published_map_at_many_is_at_for_each_stamp(stamps: list[int], steers: int) -> None:
    """The one-lookup path for an update's stamps gives exactly what at() gives per stamp,
    also when the stamps straddle a segment anchor."""
    pm = PublishedMap(max_slew=500e-6, tau_s=0.5)
    for est in moving_estimates(steers + 1, [0.0, 30e-6, 60e-6]):
        pm.steer(est) if pm.started else pm.start(est)
    anchors = pm._anchors
    base, span = anchors[0] - 500_000, anchors[-1] - anchors[0] + 1_000_000
    stamps = [base + s * span // 3_000_000 for s in stamps]  # spread over every segment
    got = pm.at_many(stamps, min(stamps), pm.segment(max(stamps)))
    assert got == [round(pm.at(b)) for b in stamps]


@settings(max_examples=50, deadline=None)
@given(st.lists(st.integers(0, 2_000_000), min_size=1, max_size=8), st.integers(1, 6))
def test_published_map_segment_cache_never_goes_stale(stamps: list[int], steers: int) -> None:
    """The sample path's cached segment (``hot``), filled before each steer, never maps with a
    segment a steer replaced or trimmed: after every steer the cached path equals at()."""
    pm = PublishedMap(max_slew=500e-6, tau_s=0.5, history=4)
    for est in moving_estimates(steers + 1, [0.0, 40e-6]):
        pm.steer(est) if pm.started else pm.start(est)
        near = [est.b_ref + s - 1_000_000 for s in stamps]
        got = pm.at_many(near, min(near), pm.segment(max(near)))
        assert got == [round(pm.at(b)) for b in near]
        assert pm.hot is not None  # filled: the next steer must drop it


def test_published_map_reaches_the_estimate_without_overshoot() -> None:
    est = ClockEstimator()
    for ex, _, _ in exchanges(0.0, 0.0, 5, 20):
        est.add(ex)
    e = est.estimate
    assert e is not None
    pm = PublishedMap(tau_s=1.0)
    pm.start(e)
    off = type(e)(**{**e.__dict__, "h_ref": e.h_ref + 100_000})  # the estimate moves 100 µs
    err = pm.steer(off)
    assert err == pytest.approx(-100_000, abs=1)
    b = max(e.b_ref, pm._floor)
    assert pm.at(b + 100_000) != pytest.approx(off.host_at(b + 100_000), abs=10)  # still slewing
    for d in (1_000_000, 5_000_000, 60_000_000):  # after tau: on the estimate, and it stays
        assert pm.at(b + d) == pytest.approx(off.host_at(b + d), abs=1)
