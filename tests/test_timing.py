"""Measuring together and acting on time (board/timing.py): the host-time grid in board ticks,
timed calls and their refusals, on a board runtime with a clock the test turns; then the daemon
keeping the boards' maps current, aligned samples on the grid, and a board without a valid map
that runs free and is said to (the status, and OFF_GRID on each such sample)."""

from __future__ import annotations

import struct
import time

import pytest

from missing_link.board.timing import MAP_LIFE_US
from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config
from missing_link.daemon.session.alignment import ECHO_LAG_NS, grid_of, off_grid
from missing_link.daemon.session.prober import map_payload
from missing_link.descriptors import Transducer
from missing_link.errors import MissingLinkError
from missing_link.j2a.codec import SOF, FrameDecoder, encode_frame
from missing_link.testing import FakeBoardClock
from missing_link.timesync import OFF_GRID
from missing_link.timesync.exchange import Exchange
from missing_link.timesync.sync import ClockSync, SyncOptions
from missing_link.topics import Topic, Update
from missing_link.virtual import make_sim
from missing_link.virtual.server import start_board_thread

from .helpers import wait_for


def board(clock: FakeBoardClock) -> object:
    rt = make_sim("aligned", 1, clock=clock)
    return rt


def call(rt: object, fn: str, payload: bytes, seq: int = 1) -> tuple[int, bytes]:
    rt.feed(encode_frame(SOF, seq, rt.index[fn], payload))  # type: ignore[attr-defined]
    (frame,) = FrameDecoder().feed(rt.take_output())  # type: ignore[attr-defined]
    return frame.opcode, frame.payload  # type: ignore[union-attr]


H0 = 1_795_000_000_123_456_789  # host ns (realtime) at board µs 5_000_000


def push_map(rt: object, ppb: int = 150_000) -> None:
    code, _ = call(rt, "a2jHostMap", struct.pack("<Qqi", 5_000_000, H0, ppb))
    assert code == 0


def test_the_grid_in_board_ticks() -> None:
    clock = FakeBoardClock(5_000_000)
    rt = board(clock)
    timing = rt.timing  # type: ignore[attr-defined]
    assert timing.next_grid(20_000, 0.0, clock.us) is None  # no map: no grid
    push_map(rt)
    for phase in (0.0, 0.25, 0.9):
        tick = timing.next_grid(20_000, phase, clock.us)
        host = timing.host_at(tick)
        p = 20_000_000
        assert tick > clock.us and tick - clock.us <= 20_000 / (1 + 150e-6) + 1
        # the tick is the last one at or before the grid instant: within one tick (1 µs) of it
        d = (host - int(phase * p)) % p
        assert p - d <= 1_001 or d == 0, (phase, d)
    clock.us += MAP_LIFE_US + 1
    assert timing.next_grid(20_000, 0.0, clock.us) is None  # an old map vouches for nothing


def test_timed_calls_and_their_refusals() -> None:
    clock = FakeBoardClock(5_000_000)
    rt = board(clock)
    trig = rt.index["a2j_trigger"]  # type: ignore[attr-defined]
    width = struct.pack("<H", 12)
    at = lambda host: struct.pack("<qB", host, trig) + width  # noqa: E731
    code, said = call(rt, "a2jAt", at(H0 + 10_000_000))
    assert (code, said) == (0xFF, b"no valid host map (a2jHostMap)")
    push_map(rt, ppb=0)
    code, said = call(rt, "a2jAt", at(H0 - 1_000_000))
    assert code == 0xFF and said.startswith(b"past by")
    code, said = call(rt, "a2jAt", at(H0 + 11_000_000_000))
    assert code == 0xFF and b"beyond what the map vouches for" in said
    code, said = call(rt, "a2jAt", struct.pack("<qB", H0, 200) + width)
    assert (code, said) == (0xFF, b"only an actuator's call or a2jGoodbye can be timed")
    code, said = call(rt, "a2jAt", at(H0 + 2_000_000))
    assert code == 0 and struct.unpack("<Q", said)[0] == 5_002_000
    for k in range(7):
        assert call(rt, "a2jAt", at(H0 + 3_000_000 + k))[0] == 0
    assert call(rt, "a2jAt", at(H0 + 4_000_000))[1] == b"timed calls queue full"
    rt.take_frames()  # type: ignore[attr-defined]
    clock.us = 5_001_999
    rt.poll()  # type: ignore[attr-defined]
    assert rt.timing.done == 0  # type: ignore[attr-defined]
    clock.us = 5_002_700  # the board got round to it late: the pulse is the timer's, on time
    rt.poll()  # type: ignore[attr-defined]
    sifs = [f for f in FrameDecoder().feed(b"".join(rt.take_frames()[1])) if f.opcode == 1]  # type: ignore[attr-defined]
    assert len(sifs) == 1
    stamp, value = struct.unpack("<QH", sifs[0].payload)
    assert (stamp, value) == (5_002_000, 12)
    code, info = call(rt, "a2jAlignInfo", b"")
    assert struct.unpack("<BIIIIII", info) == (1, 2, 0, 1, 5, 0, 0)  # (valid, age, ..., pacing)


def test_a_timed_call_acts_within_the_map_it_was_given_not_the_newer_one() -> None:
    """The board acts on the map it was given; the host maps the action's stamp with a newer
    estimate, which the exchanges since may have moved by more than its own bound: the action
    is within the given map's bound there (``given_bound_ns``), not within the newer bound.
    Deterministic: the first exchanges' replies are 4 ms slow (a busy host reading late), so
    the given map lies ~2 ms late; the next ones are fast and pin the truth to ~50 µs."""
    true_ns = lambda b: 7_000_000_000 + (b - 5_000_000) * 1000  # noqa: E731 - the truth
    sync = ClockSync(SyncOptions(res_us=1))
    sync.start(0.0)
    b = 5_000_000

    def exchange(up_ns: int, down_ns: int) -> None:
        nonlocal b
        b += 20_000
        ex = Exchange(true_ns(b) - up_ns, b, b, true_ns(b) + down_ns)
        sync.on_exchange(ex, true_ns(b) / 1e9)

    for _ in range(6):
        exchange(50_000, 4_000_000)
    est = sync.estimate
    assert est is not None
    clock = FakeBoardClock(b)
    rt = board(clock)
    assert call(rt, "a2jHostMap", map_payload(est, 0))[0] == 0
    sync.given = est  # (the prober sets it when the board has taken it)
    at = true_ns(b) + 500_000_000
    trig = rt.index["a2j_trigger"]  # type: ignore[attr-defined]
    code, reply = call(rt, "a2jAt", struct.pack("<qB", at, trig) + struct.pack("<H", 12))
    assert code == 0
    tick = struct.unpack("<Q", reply)[0]
    for _ in range(20):
        exchange(50_000, 50_000)
    rt.take_frames()  # type: ignore[attr-defined]
    clock.us = tick
    rt.poll()  # type: ignore[attr-defined]
    (sif,) = [f for f in FrameDecoder().feed(b"".join(rt.take_frames()[1])) if f.opcode == 1]  # type: ignore[attr-defined]
    stamp = struct.unpack_from("<Q", sif.payload)[0]
    mapped = sync.map(stamp)
    assert mapped is not None and stamp == tick
    early = at - mapped.host_ns
    assert early > mapped.bound_ns + 1_000_000  # the newer map's bound (and a ms) do not cover it
    within = sync.given_bound_ns(tick)
    assert within is not None and early <= mapped.bound_ns + within
    assert abs(true_ns(tick) - at) <= within  # the truth: within the given map's bound


def test_aligned_samples_fall_on_the_grid_and_free_ones_are_counted() -> None:
    clock = FakeBoardClock(5_000_000)
    rt = board(clock)
    cfg = rt.config  # type: ignore[attr-defined]
    keys = {k.name: k for k in cfg.keys}
    assert cfg.apply([(keys["signal.aligned"], True), (keys["signal.phase"], 0.5)]) is None
    stamps = []
    for _ in range(400):  # 2 s without a map: free running, each sample counted
        clock.us += 5_000
        rt.poll()  # type: ignore[attr-defined]
        for frame in FrameDecoder().feed(b"".join(rt.take_frames()[1])):  # type: ignore[attr-defined]
            stamps.append(struct.unpack_from("<Q", frame.payload)[0])
    assert rt.timing.unaligned == len(stamps) >= 90  # type: ignore[attr-defined]
    push_map(rt)  # (its reference is now a little in the past: still valid)
    clock.us = 5_000_000
    timing = rt.timing  # type: ignore[attr-defined]
    rt.config.apply([(keys["signal.aligned"], True)])  # type: ignore[attr-defined]
    stamps = []
    for _ in range(400):
        clock.us += 997  # the loop comes round at odd moments
        rt.poll()  # type: ignore[attr-defined]
        for frame in FrameDecoder().feed(b"".join(rt.take_frames()[1])):  # type: ignore[attr-defined]
            stamps.append(struct.unpack_from("<Q", frame.payload)[0])
    assert len(stamps) >= 15
    for s in stamps:  # stamped at the grid's tick, a half period off the whole 20 ms
        d = (timing.host_at(s) - 10_000_000) % 20_000_000
        assert min(d, 20_000_000 - d) <= 1_001, d


def test_the_grid_the_daemon_checks_stamps_against() -> None:
    """From the configuration: the board's whole-µs period of its float32 rate, the phase, and
    an ultrasonic ranger's lag (its ping is on the grid, its stamp at the echo's mid-flight)."""

    def topic(tid: int, prefix: str) -> Topic:
        t = Transducer(f"t{tid}", tid, prefix, "m", 1, "uint16_t", 0)
        return Topic(f"/b/t{tid}", "b", t, "missing_link_msgs/msg/T", "", None)

    topics = {0: topic(0, "ir"), 1: topic(1, "ultrasonic"), 2: topic(2, "ir")}
    values = {
        "t0.aligned": True, "t0.rate_hz": 30.0, "t0.phase": 0.25,
        "t1.aligned": True, "t1.rate_hz": 10.0,
        "t2.aligned": False, "t2.rate_hz": 10.0,
    }  # fmt: skip
    grid = grid_of(values, topics)
    assert grid == {0: (33_333_000, 8_333_250, 0), 1: (100_000_000, 0, ECHO_LAG_NS)}
    bound, slack = 5_000, 100_000
    assert not off_grid(10 * 33_333_000 + 8_333_250 + 50_000, grid[0], bound, slack)
    assert not off_grid(10 * 33_333_000 + 8_333_250 - 100_000, grid[0], bound, slack)
    assert off_grid(10 * 33_333_000 + 8_333_250 + 200_000, grid[0], bound, slack)
    assert not off_grid(7 * 100_000_000 + 12_000_000, grid[1], bound, slack)  # an echo's lag
    assert off_grid(7 * 100_000_000 - 1_000_000, grid[1], bound, slack)  # but never early
    assert off_grid(7 * 100_000_000 + 30_000_000, grid[1], bound, slack)


def test_the_daemon_keeps_the_maps_and_flags_a_board_that_runs_free() -> None:
    """Two virtual boards aligned through Daemon.configure: their samples fall on the grid in
    published host time, none flagged; a board whose a2jHostMap takes nothing runs free: the
    board counts it, the host flags every such sample OFF_GRID; a timed command in the past is
    refused with the board's reason."""
    good = make_sim("aligned", 1, name="good")
    deaf = make_sim("aligned", 2, name="deaf")
    deaf.functions[deaf.index["a2jHostMap"]] = ("a2jHostMap", 0, lambda p: (0, b""))
    servers = [start_board_thread(rt, "tcp://127.0.0.1:0") for rt in (good, deaf)]
    try:
        cfg = Config(boards=[BoardSpec(s.url) for s, _ in servers], diagnostics_period=0.3)
        with Daemon(cfg) as d:
            assert d.wait_until_up(10)
            got: dict[str, list[Update]] = {"good": [], "deaf": []}
            for n, lst in got.items():
                d.configure(n, {"signal.aligned": True, "signal.rate_hz": 50})
                d.subscribe(f"/{n}/signal", lst.append, queue=0)
            # The deaf board runs free on a period of its own, 3 ms off the grid's: at the
            # grid's own it kept the phase its first sample took, and a start within its
            # bound and GRID_SLACK_NS of an instant (0.25 ms of 20: about 1 run in 80, once
            # in make check under load) put every sample on the grid, rightly not flagged.
            # 3 ms a sample on, its phases step through the grid's 20 ms 1 ms apart: one in
            # twenty at most falls that close.
            free = next(t for t in deaf.transducers if t.name == "signal").driver
            assert free.period_us == 20_000  # (configured)
            free.period_us = 23_000
            assert wait_for(lambda: len(got["good"]) > 60 and len(got["deaf"]) > 60, 10)
            st = {s["board"]: s for s in d.status()}
            with pytest.raises(MissingLinkError, match="past by"):
                d.send("/good/trigger/cmd", 10, at_ns=time.time_ns() - 50_000_000)
            tick = d.send("/good/trigger/cmd", 10, at_ns=time.time_ns() + 200_000_000)
            assert tick is not None and tick > 0
            # how close to its time it acts: the given map's hard bound at its tick
            within = next(s for s in d.status() if s["board"] == "good")["timed_within_us"]
            assert isinstance(within, int) and 0 < within < 10_000, within
    finally:
        for s, t in servers:
            s.stop()
            t.join(5)
    synced = [u for u in got["good"][10:] if u.bound_ns >= 0]
    assert synced and not any(u.clock_flags & OFF_GRID for u in synced)
    for u in synced:
        off = u.host_ns[0] % 20_000_000
        assert min(off, 20_000_000 - off) <= u.bound_ns + 100_000
    flagged = [u for u in got["deaf"] if u.clock_flags & OFF_GRID]
    assert len(flagged) >= 0.9 * len(got["deaf"][5:])
    assert st["good"]["aligned"] == "signal" and st["good"]["map_valid"] is True
    assert st["good"]["unaligned_samples"] == 0 and st["good"]["off_grid_samples"] == 0
    assert st["deaf"]["map_valid"] is False and st["deaf"]["unaligned_samples"] > 20
    assert st["deaf"]["off_grid_samples"] > 20
