"""Acting on host time on AVR (firmware/avr/src/timing.c, trigger.c, the aligned drivers): real
AVR machine code in simavr, the rig watching the pins.  The trigger's edges are made by Timer2's
compare on OC2A; the rig models that pin from the registers (rig_sim.c) and reports edges in the
board's µs, so the edge can be held against the tick the asked host time maps to through the map
the host pushed.  The aligned Sharp's ADC conversions are seen where simavr starts them."""

from __future__ import annotations

import random
import struct
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config
from missing_link.errors import FunctionFailed
from missing_link.host.board import Board
from missing_link.timesync import OFF_GRID
from missing_link.topics import Update
from missing_link.transport import open_transport

from .helpers import AvrRig, AvrSim, wait_for

pytestmark = [pytest.mark.avr, pytest.mark.slow]
H0 = 1_795_000_000_000_000_000 + 3_456_789  # host ns of the pushed map's reference (any epoch)


@pytest.fixture
def rig(avr_rig: AvrRig) -> AvrSim:
    return avr_rig("uno_rig", skew_ppm=40)


@pytest.fixture
def mapped(rig: AvrSim) -> Iterator[tuple[Board, int]]:
    """A board handed a map (a2jHostMap): board µs b0 is host ns H0, 1 µs per 1000 ns."""
    board = Board(open_transport(rig.url), timeout=5.0)
    try:
        board.handshake()
        b0 = board.clock_exchange(5.0).t3
        board.call_ok("a2jHostMap", struct.pack("<Qqi", b0, H0, 0))
        yield board, b0
    finally:
        board.close()


def _trig(rig: AvrSim) -> tuple[int, float, float]:
    _, edges, rise, fall = rig.ctl("trig").split()
    return int(edges), float(rise), float(fall)


def _data_address(elf: Path, symbol: str) -> int:
    """Where a symbol of the firmware's RAM is, as the rig's `peek` and `stack` count."""
    nm = subprocess.run(["avr-nm", str(elf)], capture_output=True, text=True, check=True).stdout
    return next(int(x.split()[0], 16) & 0xFFFF for x in nm.splitlines() if x.endswith(" " + symbol))


def _late_pulses(rig: AvrSim, addr: int) -> int:
    """The firmware's count of pulses whose falling edge it had to force late (trigger.c,
    ``trigger_late`` at ``addr``)."""
    lo, hi = rig.ctl(f"peek {addr:x}").split()[1:3]
    return int(lo, 16) | int(hi, 16) << 8


def _edges_reach(rig: AvrSim, n: int) -> Callable[[], bool]:
    return lambda: _trig(rig)[0] >= n


def _timed_pulse(board: Board, b0: int, tick: int, width_us: int) -> int:
    at = H0 + (tick - b0) * 1000
    payload = struct.pack("<qB", at, board.index["a2j_trigger"]) + struct.pack("<H", width_us)
    return int(struct.unpack("<Q", board.call_ok("a2jAt", payload))[0])


def test_a_timed_pulse_edges_land_on_the_asked_tick(mapped: tuple[Board, int], rig: AvrSim) -> None:
    """The rising edge on OC2A is within one timer tick (0.5 µs) of the tick the host time maps
    to; the falling edge `width` later: short pulses (one compare step), one longer than
    Timer2's 128 µs wrap (steps through wraps), ticks at every phase of the 8-bit timer."""
    board, b0 = mapped
    edges = _trig(rig)[0]
    late_at = _data_address(rig.elf, "trigger_late")
    late = first = _late_pulses(rig, late_at)
    for k, width in enumerate((20, 300, 20, 1000, 55)):
        tick = _pulse_ahead(board, b0, rig, k, width)
        assert wait_for(_edges_reach(rig, edges + 2 * (k + 1)), 20), _trig(rig)
        n, rise, fall = _trig(rig)
        assert n == edges + 2 * (k + 1), (n, edges)
        assert 0 <= rise - tick <= 0.5, (k, rise, tick)
        if _late_pulses(rig, late_at) == late:
            assert fall - rise == pytest.approx(width, abs=0.5), (k, fall - rise)
        else:  # the rising edge's interrupt ran so late that the fall's match may have passed:
            late += 1  # forced then, never early (late by how late the interrupt was), counted;
            assert fall - rise >= width - 0.5, (k, fall - rise)  # short pulses only
            assert width <= 55, (k, width)
    assert late - first <= 3
    valid, _age, _unaligned, done, refused = struct.unpack("<BIIII", board.call_ok("a2jAlignInfo"))
    assert valid == 1 and done == 5 and refused == 0


def _pulse_ahead(board: Board, b0: int, rig: AvrSim, k: int, width: int) -> int:
    """A pulse asked 150 ms ahead of the board's clock, a different Timer2 phase for each k.
    Refused as past once in a CI run ("past by 3843503 us", beside background load since
    removed): simavr paces its clock to the host's and catches up flat out after falling
    behind, so a refusal is reported with the rig's lag, to tell that from a clock that jumped."""
    rig.ctl("lag")  # (from here on)
    want = board.clock_exchange(5.0).t3 + 150_000 + 37 * k
    try:
        tick = _timed_pulse(board, b0, want, width)
    except FunctionFailed as e:
        raise AssertionError(f"{e}; the rig's lag meanwhile: {rig.ctl('lag')}") from e
    assert tick == want
    return tick


def _pulse_made(rig: AvrSim, tick: int, meanwhile: Callable[[], object]) -> tuple[float, float]:
    """The rising and falling edges (board µs) of the pulse at ``tick`` once both are made,
    doing ``meanwhile`` until then (bounded: 30 s)."""
    end = time.monotonic() + 30
    while time.monotonic() < end:
        _, rise, fall = _trig(rig)
        if fall >= tick and fall > rise:
            return rise, fall
        meanwhile()
    raise AssertionError(f"no pulse at {tick}: {_trig(rig)}")


@pytest.fixture
def host_load() -> Iterator[None]:
    """A busy process beside simavr for the test's length (at most 60 s)."""
    spin = "import time\nt = time.monotonic() + 60\nwhile time.monotonic() < t: pass"
    hog = subprocess.Popen([sys.executable, "-c", spin])
    try:
        yield
    finally:
        hog.kill()
        hog.wait()


def _echo(board: Board) -> Callable[[], object]:
    return lambda: board.call("a2jEcho", bytes(200), 5.0)  # (each byte: the main loop's work)


def _held_or_counted(
    rig: AvrSim, late: int, rise: float, fall: float, tick: float, width: int
) -> None:
    """An edge on its tick (within one, 0.5 µs), or counted (trigger_late past ``late``) and
    late, never early: forced in the interrupt (by about as much as it was late) or armed late by
    a main loop held up (by the link, a loaded simulator); the fall ``width`` after the rise,
    or forced a little later (never shorter)."""
    if 0 <= rise - tick <= 0.5 and abs(fall - rise - width) <= 0.5:
        return
    assert _late_pulses(rig, _data_address(rig.elf, "trigger_late")) > late, (
        "uncounted",
        rise - tick,
        fall - rise,
        width,
    )
    assert rise - tick >= 0, (rise - tick, width)
    assert -0.5 <= fall - rise - width < 32, (fall - rise, width)


def test_timed_edges_hold_their_tick_or_are_counted_with_host_and_link_loaded(
    mapped: tuple[Board, int], rig: AvrSim, host_load: None
) -> None:
    """Issue 33.2: a compare written after the count had passed its value waited a whole Timer2
    wrap, so an edge whose interrupt came late (held off by the clock's 64-bit sums) landed
    128 µs late, uncounted.  With the host loaded and echoes keeping the link busy, 60 timed
    pulses at random phases: each edge is on its tick or counted, never a wrap off.  144 µs is
    288 ticks, a wrap and the shortest last step (32 ticks) of the old scheme: about one such
    fall in twelve came a wrap late.  (A pulse the board refuses because the loaded host sent it
    too late, or after its map had expired, is not made: the board's right answer, not what is
    tested here; another is tried, 200 at most.)"""
    board, b0 = mapped
    late_at = _data_address(rig.elf, "trigger_late")
    fn = board.index["a2j_trigger"]
    rng = random.Random(33)
    made = tries = 0
    while made < 60 and tries < 200:
        tries += 1
        width = rng.choice((144, 144, 144, 144, 20, 300, 1000))
        now = board.clock_exchange(5.0).t3
        h0 = H0 + (now - b0) * 1000
        board.call_ok("a2jHostMap", struct.pack("<Qqi", now, h0, 0))  # (fresh: 10 s of life)
        want = now + 25_000 + rng.randrange(256)
        at = struct.pack("<qB", h0 + (want - now) * 1000, fn) + struct.pack("<H", width)
        late = _late_pulses(rig, late_at)  # (before: a stalled host may read it after the pulse)
        r = board.call("a2jAt", at, 5.0)
        if r.code != 0:
            assert r.payload.startswith((b"past by", b"no valid host map")), r
            continue
        tick = int(struct.unpack("<Q", r.payload)[0])
        rise, fall = _pulse_made(rig, tick, _echo(board))
        _held_or_counted(rig, late, rise, fall, tick, width)
        made += 1
    assert made == 60, (made, tries)


def test_pulses_commanded_now_are_made_and_hold_their_width(rig: AvrSim) -> None:
    """A pulse commanded now (a2j_trigger) is made MIN_STEP ticks on, its width held or counted,
    with the link busy.  (Before, the lead was taken from a clock read that took most of it
    (hal.c's 64-bit sums), so the trigger found its tick gone and made no pulse at all.)"""
    board = Board(open_transport(rig.url), timeout=5.0)
    late_at = _data_address(rig.elf, "trigger_late")
    try:
        board.handshake()
        for k in range(100):
            width = (144, 20, 300, 1000)[k % 4]
            edges, _, _ = _trig(rig)
            late = _late_pulses(rig, late_at)
            sent = board.clock_exchange(5.0).t3
            board.call_ok("a2j_trigger", struct.pack("<H", width))
            rise, fall = _pulse_made(rig, sent, _echo(board))
            assert _trig(rig)[0] == edges + 2
            _held_or_counted(rig, late, rise, fall, rise, width)
    finally:
        board.close()


def test_refusals_say_why(mapped: tuple[Board, int]) -> None:
    board, b0 = mapped
    now = board.clock_exchange(5.0).t3
    fn = board.index["a2j_trigger"]
    past = H0 + (now - 5_000 - b0) * 1000
    with pytest.raises(FunctionFailed, match=r"past by \d+ us"):
        board.call_ok("a2jAt", struct.pack("<qB", past, fn) + b"\x14\x00")
    far = H0 + (now + 30_000_000 - b0) * 1000
    with pytest.raises(
        FunctionFailed, match=r"ms ahead: beyond what the map vouches for \(10000 ms\)"
    ):
        board.call_ok("a2jAt", struct.pack("<qB", far, fn) + b"\x14\x00")
    with pytest.raises(FunctionFailed, match=r"only an actuator.s call or a2jGoodbye can be timed"):
        board.call_ok("a2jAt", struct.pack("<qB", far, board.index["a2jGetTransds"]))
    with pytest.raises(FunctionFailed, match="expects"):
        board.call_ok("a2jAt", b"\x01\x02")
    # a host time far out of int64 range of the map (a hostile host): refused, no overflow
    with pytest.raises(FunctionFailed, match="past by"):
        board.call_ok("a2jAt", struct.pack("<qB", -(2**63), fn) + b"\x14\x00")
    with pytest.raises(FunctionFailed, match="beyond"):
        board.call_ok("a2jAt", struct.pack("<qB", 2**63 - 1, fn) + b"\x14\x00")
    refused = struct.unpack("<BIIII", board.call_ok("a2jAlignInfo"))[4]
    assert refused == 5  # (a malformed request is an error, not a refused timed call)


#: the wait's last look at TCNT1 (a tick is 8 cycles) and the call into the conversion: 1.0 to
#: 1.9 µs after the instant in simavr when no interrupt comes between
CONVERSION_NS = 3_000
#: what the rig's irqoff leaves out of a routine: its entry (4) and the one instruction the AVR
#: runs after a reti before it takes the next interrupt (5)
AROUND = 9


def _first_conversions(rig: AvrSim, since: int) -> list[float]:
    """The board µs of each sample's first conversion after ``since`` (the rig keeps the last
    64 conversions: the first of them may be a sample's second)."""
    starts = [float(x) for x in rig.ctl("adc").split()[2:]]
    return [t for i, t in enumerate(starts) if i > 0 and t - starts[i - 1] > 5_000 and t > since]


def test_aligned_adc_conversions_start_on_the_grid(mapped: tuple[Board, int], rig: AvrSim) -> None:
    """dist_ir aligned at 10 Hz, phase 0.25: each sample's first ADC conversion starts (where
    simavr starts it) on the host-time grid in board ticks, a few µs after the instant (the call
    into the conversion); three conversions per sample, as the driver takes a median.  The wait
    runs with interrupts on, so a routine that comes in its last stretch (a byte sent on the link,
    Timer1's wrap) starts it later by that routine: once each at most, a few µs apart (the rig's
    irqoff measures them).  A loaded CI run saw 5227 ns: 1039 ns, the usual, and one USART_UDRE
    routine (58 + 9 cycles) when the bound was a flat 5 µs."""
    board, b0 = mapped
    rig.ctl("irqoff")  # (from here on)
    board.configure({"dist_ir.aligned": True, "dist_ir.rate_hz": 10, "dist_ir.phase": 0.25})
    since = board.clock_exchange(5.0).t3  # (before: free running at 25 Hz)
    # eight samples of the board's time (a machine that holds the rig back: more of the host's)
    assert wait_for(lambda: len(_first_conversions(rig, since)) >= 8, 30)
    firsts = _first_conversions(rig, since)
    off = dict(place.split(":") for place in rig.ctl("irqoff").split()[1:])
    routines = sum(int(n) + AROUND for place, n in off.items() if place != "main")
    bound = CONVERSION_NS + routines * 1000 // 16  # (the main loop is the one waiting)
    lags = []
    for t in firsts:
        off_ns = (H0 + round((t - b0) * 1000) - 25_000_000) % 100_000_000
        lags.append(off_ns if off_ns < 50_000_000 else off_ns - 100_000_000)
    assert all(0 <= lag <= bound for lag in lags), (lags, bound, off)  # ns
    unaligned = struct.unpack("<BIIII", board.call_ok("a2jAlignInfo"))[2]
    assert unaligned == 0
    board.configure({"dist_ir.aligned": False})


def test_without_a_map_aligned_sampling_runs_free_and_counts(rig: AvrSim) -> None:
    board = Board(open_transport(rig.url), timeout=5.0)
    try:
        board.handshake()
        board.configure({"dist_ir.aligned": True, "dist_ir.rate_hz": 20})

        def info() -> tuple[int, ...]:
            return struct.unpack("<BIIII", board.call_ok("a2jAlignInfo"))

        # eight samples of the board's time (0.6 s of the host's made seven beside busy work)
        assert wait_for(lambda: info()[2] >= 8, 30), info()
        valid, age, _unaligned, _done, _refused = info()
        assert valid == 0 and age == 0xFFFFFFFF
    finally:
        board.close()


def test_the_daemon_times_a_trigger_and_aligns_the_rig(rig: AvrSim) -> None:
    """End to end: the daemon keeps the board's map current; a timed command acts at the asked
    host time (the published sample says so, within its bound); an aligned ranger's samples
    sit on the grid (no OFF_GRID) and the status shows the board's account."""
    fired: list[Update] = []
    ranged: list[Update] = []
    cfg = Config(boards=[BoardSpec(rig.url, timeout=2.0, uart_baud=115200)])
    with Daemon(cfg) as d:
        assert d.wait_until_up(20), d.status()
        d.subscribe("/uno_rig/camera", fired.append, queue=0)
        d.subscribe("/uno_rig/dist_ir", ranged.append, queue=0)
        rig.ctl("lag")  # (from here on)
        d.configure("uno_rig", {"dist_ir.aligned": True, "dist_ir.rate_hz": 20})
        at = time.time_ns() + 300_000_000
        tick = d.send("/uno_rig/camera/cmd", 40, at_ns=at)
        assert isinstance(tick, int)
        assert wait_for(lambda: len(fired) == 1, 5)
        u = fired[0]
        assert u.values == [40]
        # acted at the tick of the pushed map, published through the map of now: each within
        # its bound of the truth, but for how far the rate moved in the 300 ms between: simavr
        # paces its time to the host's, and on a loaded machine it falls behind now and then
        # (its "crystal" wanders by up to 1 %); the exact tick is the raw test's above
        lead_slack = 300_000_000 // 100
        assert abs(u.host_ns[0] - at) <= 2 * u.bound_ns + lead_slack, u.host_ns[0] - at
        _, _edges, rise, _fall = rig.ctl("trig").split()
        assert 0 <= float(rise) - tick <= 0.5
        n = len(ranged)
        assert wait_for(lambda: len(ranged) >= n + 20, 5)
        status = d.status()[0]
        lag_us = float(rig.ctl("lag").split()[1])
    assert status["aligned"] == "dist_ir" and status["map_valid"] is True
    # Off the grid: only what the board measured before the map reached it (and counted), unless
    # simavr fell behind the host's time (a loaded machine): then the board's clock stood still
    # for a while and caught up, which no map extrapolated over a second foresees; the daemon
    # flags and counts those samples, as it should.
    rig_kept_pace = lag_us <= 100
    if rig_kept_pace:
        assert status["off_grid_samples"] <= status["unaligned_samples"], lag_us
    assert status["timed_done"] == 1
    for x in ranged[n:]:  # each on the 50 ms grid, within what its stamp vouches for, or flagged
        assert x.values[0] is not None
        off = x.host_ns[0] % 50_000_000
        on_grid = min(off, 50_000_000 - off) <= x.bound_ns + 100_000
        assert on_grid or x.clock_flags & OFF_GRID, (off, x.bound_ns)
        assert on_grid or not rig_kept_pace, (off, x.bound_ns, lag_us)


def test_the_stack_stays_clear_of_static_ram(avr_build: Path, rig: AvrSim) -> None:
    """After calls, SIFs, configuration and timed pulses (this module's other tests run on
    their own rigs; here a short mix), the lowest stack pointer is above the end of .bss."""
    elf = avr_build / "uno_rig" / "firmware.elf"
    end = _data_address(elf, "_end")
    board = Board(open_transport(rig.url), timeout=5.0)
    try:
        board.handshake()
        board.config()
        b0 = board.clock_exchange(5.0).t3
        board.call_ok("a2jHostMap", struct.pack("<Qqi", b0, H0, 0))
        board.configure({"dist_ir.aligned": True, "wheel.aligned": True})
        _timed_pulse(board, b0, board.clock_exchange(5.0).t3 + 50_000, 300)
        rig.ctl("enc 200")
        time.sleep(0.5)
    finally:
        board.close()
    low = int(rig.ctl("stack").split()[1], 16)
    assert low - end >= 64, f"stack reached 0x{low:04x}, .bss ends at 0x{end:04x}"
