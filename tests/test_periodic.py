"""A Periodic (board/drivers) beside a driver that blocks the board's one loop, on a clock the test
turns: a compass beside the rover's 10 Hz HC-SR04, whose echo wait held the MicroPython rover's
loop 26 to 33 ms each ranging (measured in the simulator on a quiet machine: the echo's timeout
at ``max_range_cm`` 400).  A compass slot the ranging covers is measured late, the next one on
time: the rate holds, the intervals alternate, and a slot covered whole is skipped, never
measured twice in a row (the loop's time was the one from before the ranging: a 50 Hz compass
measured twice within 0 ms of each other, the MicroPython rover's IMU and compass within 1 to
5 ms).  How the tests read a rate from the stamps (helpers.period_seen_us) must see 20 Hz there;
the median interval did not (the update tests saw 33 ms for 20 Hz, once)."""

from __future__ import annotations

import itertools
import statistics

from missing_link.board.drivers import Periodic
from missing_link.testing import FakeBoardClock

from .helpers import period_seen_us

BLOCK_US = 27_000  # one ranging: what the sonar's poll took (26 to 33 ms)


class Stamps(Periodic):
    """A transducer that stamps each measurement with the clock then (as the compass does)."""

    def __init__(self, clock: FakeBoardClock, rate_hz: float) -> None:
        super().__init__(clock, rate_hz)
        self.stamps: list[int] = []

    def measure(self, now: int) -> None:
        self.stamps.append(self.clock())


class Blocker(Periodic):
    """A ranger that holds the loop while it waits for its echo."""

    def measure(self, now: int) -> None:
        self.clock.advance(BLOCK_US)


def run(rate_hz: float, seconds: float) -> list[int]:
    """The loop as the firmware's: poll every driver at the clock's time, then sleep until the
    soonest one is due.  The sonar's rangings begin just before every other compass slot (as
    they did on the rover, a few ms before): here, on the same slot, polled first."""
    clock = FakeBoardClock(start_us=0)
    compass = Stamps(clock, rate_hz)
    sonar = Blocker(clock, 10)
    while clock.us < seconds * 1e6:
        now = clock()
        for driver in (sonar, compass):
            driver.poll(now)
        clock.us = max(clock.us, min(sonar.next_due_us(), compass.next_due_us()))
    return compass.stamps


def test_a_rate_beside_a_driver_that_blocks_the_loop_is_read_from_its_slots() -> None:
    stamps = run(20, 10)
    gaps = [b - a for a, b in itertools.pairwise(stamps)]
    assert len(stamps) == 200  # 20 Hz: its rate holds, no slot lost, none added
    assert set(gaps) == {23_000, 77_000}  # late by the ranging, then on its slot
    # the median of an odd number of intervals, from a late sample: the short one
    assert statistics.median(gaps[:31]) == 23_000
    for start in range(len(stamps) - 31):  # every window of 31 samples the tests might see
        assert 45_000 < period_seen_us(stamps[start : start + 31]) <= 50_000


def test_a_slot_the_blocking_covers_is_skipped_not_measured_twice() -> None:
    """At 50 Hz the ranging (27 ms) covers a whole slot: lost, no burst after it."""
    stamps = run(50, 10)
    gaps = [b - a for a, b in itertools.pairwise(stamps)]
    assert len(stamps) == 400  # one slot of five lost to each ranging
    assert set(gaps) == {20_000, 40_000}  # (0 and 13 ms when it went by the loop's old time)
    for start in range(len(stamps) - 31):
        assert period_seen_us(stamps[start : start + 31]) == 24_000  # (2 rangings in 10)
