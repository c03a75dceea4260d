"""A free-running driver's measurement kept off the instants the board must be on time for
(board/pacing.py), on a clock the test turns: the board's one loop turns every TURN_US, an
aligned Periodic measures on a 10 Hz host-time grid, and a free-running one holds the loop while
it measures (the thesis rig's MPU-6050: about 2 ms of a Pico's time an I2C read; the rover's
HC-SR04: 30 ms waiting for its echo).  Without pacing, a hold that starts just before an instant
made the aligned measurement late by what was left of it (the rig under MicroPython: 16 of 602
aligned ADC reads over 2 ms late)."""

from __future__ import annotations

import itertools
import struct

from missing_link.board.drivers import Periodic
from missing_link.board.runtime import BoardRuntime
from missing_link.board.timing import MARGIN_US, Timing
from missing_link.board.transducer import Transducer
from missing_link.daemon.session.alignment import parse_align_info
from missing_link.j2a.codec import SOF, FrameDecoder, encode_frame
from missing_link.testing import FakeBoardClock

TURN_US = 250  # a loop turn's own work
GRID_US = 100_000  # the aligned transducer's period: 10 Hz


class Measures(Periodic):
    """A Periodic that notes when it measured and holds the loop `hold_us` doing it."""

    def __init__(self, clock: FakeBoardClock, rate_hz: float, hold_us: int = 0) -> None:
        Periodic.__init__(self, clock, rate_hz)
        self.hold_us = hold_us
        self.at: list[int] = []

    def measure(self, now: int) -> None:
        self.at.append(self.clock())
        self.clock.advance(self.hold_us)
        self.emit(0, 1)


def rig(hz: float, hold_us: int, grid_us: int = GRID_US) -> tuple[BoardRuntime, Measures, Measures]:
    """A board with a free-running driver (polled first) and an aligned one on the grid of
    `grid_us` (the host's map: board µs = host µs, so the grid's instants are multiples of it)."""
    clock = FakeBoardClock(1_000_000)
    rt = BoardRuntime("paced", "test", "p-1", clock=clock)
    rt.timing = Timing(rt)
    held = Measures(clock, hz, hold_us)
    aligned = Measures(clock, 1_000_000 / grid_us)
    aligned.aligned, aligned.timing = True, rt.timing
    for i, drv in enumerate((held, aligned)):
        rt.add_transducer(Transducer(f"t{i}", i + 1, "p", "m", 1, "uint8_t", 0), drv)
    rt.host_map = (6_000_000, 6_000_000_000, 0)  # (vouches for the 10 s run: MAP_LIFE_US)
    return rt, held, aligned


def run(rt: BoardRuntime, seconds: float) -> None:
    clock = rt.clock
    end = clock() + int(seconds * 1_000_000)
    while clock() < end:
        rt.poll()
        rt.take_frames()
        clock.advance(TURN_US)  # type: ignore[attr-defined]


def lateness(aligned: Measures, grid_us: int = GRID_US) -> list[int]:
    return [t % grid_us for t in aligned.at]


def test_an_imu_read_waits_for_room_before_an_aligned_instant() -> None:
    """A 97 Hz measurement holding the loop 2 ms drifts through every phase of a 10 Hz grid in
    10 s: without pacing 19 of the 99 aligned measurements were late by 1 to 2 ms (the IMU's
    read under way at the instant); now a read waits for room, and the aligned ones are on time
    (31 reads put off, the rate held)."""
    rt, held, aligned = rig(97, 2_000)
    run(rt, 10)
    assert len(aligned.at) >= 99
    assert max(lateness(aligned)) <= TURN_US  # the loop's own turn, never the IMU's read
    pacing = rt.pacing
    assert pacing.deferred > 0 and pacing.overlaps == 0
    assert pacing.longest[1] == 2_000
    # put off, not lost or doubled: the rate holds and no two reads come closer than a period
    # less the most a read waits (its hold, the margin, a turn)
    slots = (held.at[-1] - held.at[0]) / (1_000_000 // 97)
    assert abs(len(held.at) - 1 - slots) < 1
    assert held.at[0] - 1_000_000 <= GRID_US + TURN_US  # (its first, not timed: after an instant)
    gaps = [b - a for a, b in itertools.pairwise(held.at)]
    assert min(gaps) >= 1_000_000 // 97 - (2_000 + MARGIN_US + 2 * TURN_US)
    # the host reads the counts in a2jAlignInfo
    rt.feed(encode_frame(SOF, 1, rt.index["a2jAlignInfo"], b""))
    (frame,) = FrameDecoder().feed(rt.take_output())
    assert struct.unpack("<BIIIIII", frame.payload)[5:] == (pacing.deferred, pacing.overlaps)


def test_a_ranging_longer_than_the_grid_runs_right_after_an_instant_and_is_never_starved() -> None:
    """A 30 ms hold (a part's wait; the HC-SR04 itself is not paced: hcsr04.py) at 10 Hz beside
    a 100 Hz grid never finds room: it waits out one instant and runs right after it, at its
    rate, reaching the next instants (as any start would) and said so.  Its first measurement,
    not yet timed, runs when due (the next instant 10 ms ahead: the margin alone is its room)."""
    rt, held, aligned = rig(10, 30_000, grid_us=10_000)
    run(rt, 10)
    assert 99 <= len(held.at) <= 101  # its rate: never starved
    after = [t % 10_000 for t in held.at]
    assert max(after) <= 3 * TURN_US  # right after an instant (its aligned read, a turn)
    gaps = [b - a for a, b in itertools.pairwise(held.at)]
    assert min(gaps) >= 100_000 - 10_000 - 3 * TURN_US  # late by one grid period at most
    # each put off but the first (not timed yet), and each reaching the next instant
    assert rt.pacing.deferred == len(held.at) - 1 and rt.pacing.overlaps == len(held.at)
    # two instants a ranging lost (as it did when it ran at its due, on an instant), the one it
    # ends in measured as the loop gets there: the ranging's end and a turn
    assert len(aligned.at) >= 1000 - 2 * len(held.at) - 1
    assert max(lateness(aligned, 10_000)) <= 2 * TURN_US


def test_without_a_map_or_timed_call_nothing_waits() -> None:
    """No instant to be on time for: a free-running measurement runs when due (timed all the
    same, so its room is known when a map comes)."""
    rt, held, _aligned = rig(97, 2_000)
    rt.host_map = None
    run(rt, 1)
    assert rt.pacing.deferred == 0 and len(held.at) == 97
    assert rt.pacing.longest[1] == 2_000


def test_while_a_measurement_waits_the_loop_sleeps_until_the_instant() -> None:
    """The loop's next deadline is the instant a measurement waits out, not its own due that
    has gone by: a loop that spun on it made garbage every turn, and on the rover the allocator
    collected on the grid."""
    rt, held, _aligned = rig(97, 2_000)
    clock = rt.clock
    waited = []
    while clock() < 3_000_000:  # type: ignore[operator]
        rt.poll()
        due = held.next_due_us()
        if due is not None and due <= clock() and held.at:  # put off this turn
            deadline = rt.next_deadline_us()
            assert deadline is not None and deadline >= clock()  # (the instant: now, or ahead)
            assert deadline % GRID_US == 0  # (the aligned instant)
            waited.append(deadline)
        clock.advance(TURN_US)  # type: ignore[attr-defined]
    assert waited


def test_the_host_reads_the_counts_and_an_avr_boards_reply_without_them() -> None:
    head = struct.pack("<BIIII", 1, 5, 0, 2, 1)
    avr = parse_align_info(head)
    assert (
        avr.problem == "" and avr.polls_deferred is None and "polls_deferred" not in avr.figures()
    )
    py = parse_align_info(head + struct.pack("<II", 31, 0))
    assert (py.polls_deferred, py.poll_overlaps) == (31, 0)
    assert py.figures()["polls_deferred"] == 31 and py.figures()["timed_done"] == 2
    assert parse_align_info(head + b"\0").problem == "a reply of 18 bytes, not 17 or 25"


def test_a_first_measurement_does_not_wait_for_a_far_instant() -> None:
    """F1: a driver not yet timed waits out only an instant that is close (within the margin:
    its poll's length is not known yet), never a far one: beside a 0.1 Hz aligned driver (its
    instant 9 s ahead) the 97 Hz reads start at once and keep their rate (they did none in 3 s,
    waiting for that instant), and the same beside a timed call 9 s ahead and nothing aligned."""
    rt, held, _aligned = rig(97, 2_000, grid_us=10_000_000)
    run(rt, 3)
    assert len(held.at) >= 3 * 97 - 1 and held.at[0] - 1_000_000 <= TURN_US
    assert rt.pacing.overlaps == 0 and rt.pacing.deferred == 0

    rt, held, _aligned = rig(97, 2_000)
    rt.transducers[1].set_enabled(False)  # (no grid: only the timed call's instant)
    rt.add_function("act", lambda payload: (0, b""))
    rt.timing.calls = ("act",)  # (an actuator's command: timeable)
    at = struct.pack("<q", 10_000_000 * 1000) + bytes([rt.index["act"]])
    rt.feed(encode_frame(SOF, 1, rt.index["a2jAt"], at))
    assert rt.timing.next_precise_us() == 10_000_000, FrameDecoder().feed(rt.take_output())
    run(rt, 3)
    assert len(held.at) >= 3 * 97 - 1 and held.at[0] - 1_000_000 <= TURN_US


def test_a_wait_left_over_across_disable_and_enable_does_not_skip_the_room_check() -> None:
    """F2: a measurement put off for an instant, its driver disabled past that instant and
    enabled again just before another (room for less than its poll): it waits that one out
    (it ran at once, into the instant: the wait left over counted as one served)."""
    rt, held, aligned = rig(97, 2_000)
    clock = rt.clock
    while not rt.pacing.waits:  # (until a read is put off)
        rt.poll()
        rt.take_frames()
        clock.advance(TURN_US)  # type: ignore[attr-defined]
    t = rt.transducers[0]
    t.set_enabled(False)
    for _ in range(3):  # (the loop turns while it is off)
        clock.advance(50_000)  # type: ignore[attr-defined]
        rt.poll()
    reads, late = len(held.at), len(aligned.at)
    clock.advance((clock() // GRID_US + 2) * GRID_US - 1_500 - clock())
    t.set_enabled(True)
    rt.poll()  # (due long since: 1.5 ms before an instant, a 2 ms read has no room)
    assert len(held.at) == reads and rt.pacing.overlaps == 0
    run(rt, 0.5)
    # (the aligned read due while the clock jumped, at once; the next on their instants)
    assert len(aligned.at) > late + 1 and max(lateness(aligned)[late + 1 :]) <= TURN_US
    assert len(held.at) > reads and rt.pacing.overlaps == 0


def test_two_reads_after_the_instant_they_waited_out_do_not_both_run_into_the_next() -> None:
    """F3: two paced drivers that waited out the same instant: the first runs right after it,
    the second's room is what the first left (it ran at once too, back to back, into the next
    instant: 26 polls did in 5 s, the aligned reads 2.5 ms late); it waits the next one out, and
    not a second time (never starved)."""
    clock = FakeBoardClock(1_000_000)
    rt = BoardRuntime("paced", "test", "p-1", clock=clock)
    rt.timing = Timing(rt)
    first, second = Measures(clock, 15, 6_000), Measures(clock, 15, 6_000)
    aligned = Measures(clock, 100)
    aligned.aligned, aligned.timing = True, rt.timing
    for i, drv in enumerate((first, second, aligned)):
        rt.add_transducer(Transducer(f"t{i}", i + 1, "p", "m", 1, "uint8_t", 0), drv)
    rt.host_map = (6_000_000, 6_000_000_000, 0)
    run(rt, 5)
    assert rt.pacing.overlaps <= 2  # (the first reads, not timed: at once, into an instant)
    assert max(lateness(aligned, 10_000)[10:]) <= TURN_US
    for drv in (first, second):
        assert abs(len(drv.at) - 75) <= 2  # their rate (15 Hz): neither starved
        gaps = [b - a for a, b in itertools.pairwise(drv.at)]
        assert max(gaps) <= 66_666 + 2 * 10_000 + 2 * TURN_US  # (two instants waited out at most)


class SlowTiming(Timing):
    """Timing whose instant lookup takes board time, as its grid maths do on a Pico (big
    integers of host ns): the fake clock advances `cost_us` in each next_instant."""

    def __init__(self, rt: BoardRuntime, cost_us: int) -> None:
        Timing.__init__(self, rt)
        self.cost_us = cost_us
        self.lookups = 0

    def next_instant(self, now: int) -> int | None:
        self.lookups += 1
        self.rt.clock.advance(self.cost_us)  # type: ignore[attr-defined]
        return Timing.next_instant(self, now)  # type: ignore[no-any-return]


class Stamps(Measures):
    """A Measures that stamps its sample with the `now` it is handed (as analog.py, sharp.py,
    battery.py do) and notes how long before its read that stamp is."""

    def __init__(self, clock: FakeBoardClock, rate_hz: float, hold_us: int = 0) -> None:
        Measures.__init__(self, clock, rate_hz, hold_us)
        self.early: list[int] = []

    def measure(self, now: int) -> None:
        self.early.append(self.clock() - now)
        Measures.measure(self, now)


def test_a_paced_sample_is_stamped_when_it_is_read_not_when_its_room_was_looked_up() -> None:
    """E: pacing read the clock, looked up the next instant (timing.instant_kept: its grid
    maths cost a Pico board time) and handed the poll the clock read before the lookup; a
    driver stamping with it (analog.py, sharp.py, battery.py) stamped its sample up to that
    lookup's time before its read (29 of 290 samples 300 µs early with a 300 µs lookup)."""
    clock = FakeBoardClock(1_000_000)
    rt = BoardRuntime("paced", "test", "p-1", clock=clock)
    rt.timing = timing = SlowTiming(rt, 300)
    free = Stamps(clock, 100, 200)
    aligned = Stamps(clock, 10)
    aligned.aligned, aligned.timing = True, timing
    for i, drv in enumerate((free, aligned)):
        rt.add_transducer(Transducer(f"t{i}", i + 1, "p", "m", 1, "uint8_t", 0), drv)
    rt.host_map = (6_000_000, 6_000_000_000, 0)
    run(rt, 3)
    assert timing.lookups > 10 and len(free.early) >= 3 * 100 - 10  # (looked up; its rate)
    assert max(free.early) == 0, sum(e > 0 for e in free.early)  # each stamped at its read
    assert rt.pacing.longest[1] == 200  # (its poll's length, not the lookup's with it)
