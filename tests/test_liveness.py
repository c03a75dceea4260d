"""A frozen or half-open board is found in time (daemon/session/liveness.py, session.py's
``serve``), whatever is queued on its link: the watch's rules on virtual time; the supervisor on
virtual time against a board that never answers (it must not wait for it); and real board processes
of every kind (the CPython virtual thesis and rangers boards, the MicroPython firmware under node,
the AVR firmware in simavr), frozen with SIGSTOP or cut off by a relay that stops forwarding, while
commands and a control call with an absurd timeout are in flight.  Waits on real processes are
bounded but generous (bench/bench_liveness.py measures how fast)."""

from __future__ import annotations

import signal
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import Future
from contextlib import contextmanager
from pathlib import Path
from typing import Any, cast

import pytest

from missing_link.daemon import Daemon
from missing_link.daemon.claims import Claims
from missing_link.daemon.config import BoardSpec, Config
from missing_link.daemon.control.allowlist import CommandGate
from missing_link.daemon.control.endpoint import ask
from missing_link.daemon.fanout import Fanout
from missing_link.daemon.session.context import SessionContext
from missing_link.daemon.session.liveness import LinkWatch
from missing_link.daemon.session.session import BoardSession, LinkStale
from missing_link.daemon.session.status import SessionState
from missing_link.descriptors import parse_transds
from missing_link.host.board import Board
from missing_link.host.link import CallResult
from missing_link.publishers.bus import Bus
from missing_link.ros.msgs import typestore_for
from missing_link.testing import FakeClock
from missing_link.virtual import make_sim
from missing_link.virtual.faults import FaultRelay
from missing_link.virtual.process import start_board_process, stop_process

from .helpers import AvrRig, FirmwareSim, wait_for

ROOT = Path(__file__).resolve().parent.parent
RIG = ROOT / "examples" / "boards" / "thesis-rig.py"
Serve = Callable[..., Any]


# ---- the watch's rules, on virtual time ---------------------------------------------------------
def run_watch(
    watch: LinkWatch,
    frames: Callable[[float], float],
    keep: float | None,
    until: float,
    now: float = 0.0,
) -> list[tuple[float, str]]:
    """Drive ``watch`` as the supervisor does from ``now``, sleeping exactly as long as it
    says; ``frames(now)``: the last frame's time then.  Returns (time, what) for all it did."""
    out: list[tuple[float, str]] = []
    while now < until:
        now += watch.wait_s(now, frames(now), keep)
        turn = watch.turn(now, frames(now), keep)
        if turn.stale:
            out.append((now, "stale"))
            break
        out += [(now, w) for w in ("heartbeat", "keepalive", "ping") if getattr(turn, w)]
    return out


def test_a_silent_link_is_stale_at_link_timeout_with_heartbeats_before() -> None:
    watch = LinkWatch(link_timeout=1.5, period=1.0, now=0.0)
    did = run_watch(watch, lambda now: 0.0, keep=0.5 / 3, until=10.0)
    assert did[-1] == (1.5, "stale")  # not a wake-up later
    beats = [t for t, what in did if what == "heartbeat"]
    assert beats == [0.75, 1.125]  # half of it, then every quarter
    keeps = [t for t, what in did if what == "keepalive"]
    assert keeps[0] == 0.0 and len(keeps) == 9 and max(keeps) < 1.5  # every third of 500 ms
    assert [t for t, what in did if what == "ping"] == [0.0, 1.0]


def test_silence_while_the_host_was_stopped_is_not_the_boards() -> None:
    """A host process stopped or starved for longer than link_timeout (its reading thread
    too: the board's frames wait in the kernel) wakes to a silence that is its own: the watch
    asks the board and gives it half a timeout before a verdict.  A board that stays silent
    through it is stale; one whose waiting frames are read in time is not."""
    for answers in (False, True):
        watch = LinkWatch(link_timeout=1.5, period=10.0, now=0.0)
        watch.turn(watch.wait_s(0.0, 0.0, None), 0.0, None)  # (the first ping)
        assert watch.wait_s(0.0, 0.0, None) == 0.75
        turn = watch.turn(5.0, 0.0, None)  # woke 4.25 s late: the host was not running
        assert not turn.stale and turn.heartbeat and watch.host_stalls == 1
        assert turn.host_late == pytest.approx(4.25)
        heard = 5.001 if answers else 0.0  # the reading thread reads what waited
        did = run_watch(watch, lambda now, heard=heard: heard, keep=None, until=5.75, now=5.0)
        assert did == (
            [(5.751, "heartbeat")] if answers else [(5.375, "heartbeat"), (5.75, "stale")]
        )
    # once per silence: a host late again and again does not put off a dead board's verdict
    for t, late in ((1.5, 0.38), (1.5, 2.0), (0.2, 0.051)):
        watch, now = LinkWatch(link_timeout=t, period=60.0, now=0.0), 0.0
        for _ in range(1000):
            now += watch.wait_s(now, 0.0, None) + late
            if watch.turn(now, 0.0, None).stale:
                break
        assert now <= 1.5 * t + 2 * late, (t, late, now)  # (T + T/2 and the wake-ups' lateness)
        assert watch.host_stalls >= 1
    # a supervisor on time is judged as before: the verdict at link_timeout
    on_time = LinkWatch(link_timeout=1.5, period=10.0, now=0.0)
    assert run_watch(on_time, lambda now: 0.0, keep=None, until=5.0)[-1] == (1.5, "stale")
    assert on_time.host_stalls == 0


def test_a_talking_link_is_never_stale_and_a_quiet_one_is_asked_in_time() -> None:
    watch = LinkWatch(link_timeout=1.5, period=1.0, now=0.0)
    did = run_watch(watch, lambda now: now - now % 0.1, keep=None, until=60.0)  # 10 frames/s
    assert "stale" not in {w for _t, w in did} and "heartbeat" not in {w for _t, w in did}
    # a quiet board that answers every heartbeat at once is never stale either
    heard = [0.0]
    quiet = LinkWatch(link_timeout=1.5, period=1.0, now=0.0)
    now = 0.0
    while now < 60.0:
        now += quiet.wait_s(now, heard[0], None)
        turn = quiet.turn(now, heard[0], None)
        assert not turn.stale
        if turn.heartbeat:
            heard[0] = now + 0.01  # its answer
    # the supervisor sleeps at most a second, and never past the instant of a verdict
    assert LinkWatch(1.5, 5.0, 0.0).wait_s(0.0, 0.0, None) == 0.0  # (the first ping)
    w = LinkWatch(1.5, 5.0, 0.0)
    w.turn(0.0, 0.0, None)
    assert w.wait_s(0.0, 0.0, None) == 0.75  # to the heartbeat
    assert w.turn(1.0, -0.49, None).heartbeat  # (the next one a quarter later: 1.375) ...
    assert w.wait_s(1.0, -0.49, None) == pytest.approx(0.01)  # ... but the verdict is at 1.01


# ---- the supervisor, on virtual time, with a board that never answers ---------------------------
def virtual_clock(until: float = 1e9, on_until: Callable[[], None] = lambda: None) -> FakeClock:
    """The supervisor's clock: the shipped fake, each ``wait`` moving time on by its timeout at
    once (autojump); ``on_until()`` once it reaches ``until`` s."""
    clock = FakeClock(start=100.0, autojump=True)
    moves = [0]

    def moved() -> None:
        moves[0] += 1
        assert moves[0] < 100_000, "the supervisor spins"
        if clock.monotonic() >= until:
            on_until()

    clock.watch(moved)
    return clock


class MuteBoard:
    """A board that takes every request and answers none (frozen, or a half-open link); a
    blocking call is a test failure: the supervisor must never wait for the board."""

    index = {n: i for i, n in enumerate(
        ["a2jEcho", "a2jFailsafe", "a2jAlignInfo", "a2j_set_servo", "a2jAt", "a2jGoodbye"]
    )}  # fmt: skip
    functions = list(index)
    properties: dict[str, str] = {}
    name = url = "mute://"
    alive = True

    def __init__(self, clock: FakeClock, answer: bool = False) -> None:
        self.clock = clock
        self.answer = answer  # a healthy board instead: every call answered at once
        self.last_frame = clock.monotonic()
        self.calls: list[str] = []

    def call_future(
        self, name: str, payload: bytes = b"", timeout: float | None = None
    ) -> Future[CallResult]:
        self.calls.append(name)
        fut: Future[CallResult] = Future()
        if self.answer:
            self.last_frame = self.clock.monotonic()
            fut.set_result(CallResult(0, b"\0" * 8 if name == "a2jFailsafe" else b""))
        return fut

    def call(self, *args: Any, **kw: Any) -> Any:
        raise AssertionError("the supervisor waited for the board")

    call_ok = call

    def on_close(self, fn: Callable[[], None]) -> None:
        pass


def mute_session(clock: FakeClock, timeout: float = 10.0) -> BoardSession:
    ctx = SessionContext(
        config=Config(diagnostics_period=1.0),
        reactor=None,
        typestore=typestore_for("jazzy"),
        realtime_offset_ns=0,
        probe_gap=lambda: 0.05,
        claims=Claims("missing_link_msgs"),  # (the daemon's own claims and a fan-out to no face)
        faces=Fanout([], Bus(), CommandGate(["**"]), lambda *args, **face: {}),
        clock=clock,
    )
    # a call timeout of 10 s: a supervisor that waited for a call would wait that long
    session = BoardSession(ctx, BoardSpec("mute://", timeout=timeout, link_timeout=1.5))
    session.run_config.values = {"servo.failsafe_ms": 500}  # a failsafe: keepalives
    return session


def test_the_supervisor_finds_a_mute_board_at_link_timeout_without_waiting_for_it() -> None:
    clock = virtual_clock()
    session = mute_session(clock)
    board = MuteBoard(clock)
    (servo,) = parse_transds("transds/1\nservo,3,servo,S,1,int8_t,-1,call=a2j_set_servo\n")
    command = session.actuators.handler(servo)
    command(10)
    with pytest.raises(LinkStale, match=r"no frame from the board for 1\.5 s"):
        session.serve(cast(Board, board))
    # found at link_timeout, exactly
    assert clock.monotonic() - board.last_frame == pytest.approx(1.5)
    assert session.stale_links == 1
    # one of each in flight, never a backlog: a keepalive was due nine times, a command came
    # twice, the counts and the round trip twice (the first of each never answered)
    assert board.calls.count("a2jEcho") == 2  # the keepalive's and the round trip's
    assert board.calls.count("a2jFailsafe") == 1 and board.calls.count("a2j_set_servo") == 1
    assert session.reads.keepalive.call.skipped >= 7


def test_the_supervisor_keeps_a_healthy_quiet_board_up_and_talking() -> None:
    session: BoardSession
    clock = virtual_clock(until=159.5, on_until=lambda: session.request_stop())
    session = mute_session(clock)
    board = MuteBoard(clock, answer=True)
    session.serve(cast(Board, board))  # returns when stopped: never stale
    assert session.stale_links == 0
    assert board.calls.count("a2jFailsafe") == 60  # once a second
    assert board.calls.count("a2jEcho") > 60 * 6  # keepalives (6/s) and round trips (1/s)
    assert session.reads.failsafe.status.trips == 0


# ---- real boards of every kind, frozen or cut off, with commands and a control call out ---------
class Rig:
    def __init__(self, url: str, freeze: Callable[[bool], None], servo: str | None) -> None:
        self.url, self.freeze, self.servo = url, freeze, servo


def signaller(proc: subprocess.Popen[str]) -> Callable[[bool], None]:
    return lambda on: proc.send_signal(signal.SIGSTOP if on else signal.SIGCONT)


@contextmanager
def board_proc(sim: str) -> Iterator[Rig]:
    proc, url = start_board_process(sim, 1, listen="tcp://127.0.0.1:0")
    try:
        yield Rig(url, signaller(proc), "/thesis/servo/cmd" if sim == "thesis" else None)
    finally:
        proc.send_signal(signal.SIGCONT)
        stop_process(proc)


def commanding(d: Daemon, topic: str | None, stop: threading.Event) -> None:
    k = 0
    while topic is not None and not stop.wait(0.02):
        try:
            d.send(topic, k % 50 - 25)
        except KeyError:
            pass  # (down: no command topic now)
        k += 1


def found_while_busy(rig: Rig, tmp_path: Path, **spec: Any) -> None:
    """Up, then commands every 20 ms; freeze; a control call with a timeout of 1e308 s at
    once: the board must be found lost, the call answered, and the board up again after."""
    sock = str(tmp_path / "c.sock")
    cfg = Config(boards=[BoardSpec(rig.url, **spec)], control=sock, backoff_max=0.5)
    with Daemon(cfg) as d:
        assert d.wait_until_up(30), d.status()
        s = d.sessions[0]
        stop = threading.Event()
        cmd = threading.Thread(target=commanding, args=(d, rig.servo, stop), daemon=True)
        cmd.start()
        answers: list[dict[str, Any]] = []
        try:
            time.sleep(1.2)
            rig.freeze(True)
            t0 = time.monotonic()
            request = {"op": "call", "board": s.name, "function": "a2jEcho", "timeout": 1e308}
            control = threading.Thread(target=lambda: answers.append(ask(sock, request, 60)))
            control.start()
            lost = wait_for(lambda: s.state != SessionState.UP, 15)
            lost_after = time.monotonic() - t0
            assert lost, f"still up after 15 s: {s.status()}"
            assert "no frame from the board" in s.error
            control.join(15)
            (answer,) = answers  # the link failed under the call, which said so
            assert answer.get("kind") == "board" and "internal" not in answer["error"], answer
            print(f"{rig.url}: lost after {lost_after:.2f} s")
        finally:
            rig.freeze(False)
            stop.set()
            cmd.join(5)
        assert wait_for(lambda: s.state == SessionState.UP, 30), s.status()  # and back
        assert d.status()[0]["stale_links"] == 1


@pytest.mark.slow
@pytest.mark.parametrize("sim", ["thesis", "rangers"])
def test_a_frozen_virtual_board_is_found_while_calls_are_out(sim: str, tmp_path: Path) -> None:
    with board_proc(sim) as rig:
        found_while_busy(rig, tmp_path)


@pytest.mark.slow  # (seconds of real time)
def test_a_half_open_link_is_found_while_calls_are_out(serve: Serve, tmp_path: Path) -> None:
    server = serve(make_sim("thesis", seed=2), listen="tcp://127.0.0.1:0")
    with FaultRelay(server.url) as relay:
        found_while_busy(Rig(relay.url, relay.blackhole, "/thesis/servo/cmd"), tmp_path)


@pytest.mark.slow
@pytest.mark.micropython
def test_a_frozen_micropython_board_is_found_while_calls_are_out(tmp_path: Path) -> None:
    sim = FirmwareSim(RIG)
    try:
        found_while_busy(Rig(sim.url, signaller(sim.proc), "/rig/servo/cmd"), tmp_path)
    finally:
        sim.proc.send_signal(signal.SIGCONT)
        sim.close()


@pytest.mark.slow
def test_a_frozen_avr_board_is_found_while_calls_are_out(avr_rig: AvrRig, tmp_path: Path) -> None:
    rig = avr_rig("uno_rig")
    try:
        found_while_busy(
            Rig(rig.url, signaller(rig.proc), "/uno_rig/servo/cmd"), tmp_path, uart_baud=115200
        )
    finally:
        rig.proc.send_signal(signal.SIGCONT)
