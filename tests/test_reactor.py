"""The shared I/O loop and the work that runs on it: several boards read by one thread, calls
from other threads, the ticker (periodic work without a thread hand-off), asynchronous clock
exchanges, and the daemon's clock-probe budget."""

from __future__ import annotations

import itertools
import socket
import threading
from concurrent.futures import Future
from typing import Any

import pytest

from missing_link.daemon.config import BoardSpec
from missing_link.daemon.session.prober import ClockProber, ProbeContext
from missing_link.errors import CallTimeout
from missing_link.host.board import Board
from missing_link.host.reactor import Reactor
from missing_link.j2a import SifReceived
from missing_link.testing import FakeClock
from missing_link.timesync import ClockSync, Exchange, SyncOptions
from missing_link.timesync.sync import BURST, TRACKING
from missing_link.transport import open_transport
from missing_link.virtual.sims import make_sim

from .helpers import wait_for

Serve = Any


@pytest.fixture
def reactor() -> Any:
    r = Reactor(batch_s=0.002).start()
    yield r
    r.stop()


def _board(url: str, reactor: Reactor) -> Board:
    b = Board(open_transport(url), timeout=2.0, reactor=reactor)
    b.handshake()
    return b


def test_one_loop_reads_several_boards_and_serves_calls_from_other_threads(
    serve: Serve, reactor: Reactor
) -> None:
    servers = [
        serve(make_sim("rate", seed=k, name=f"r{k}", rate_hz=200.0), "tcp://127.0.0.1:0")
        for k in range(3)
    ]
    boards = [_board(s.url, reactor) for s in servers]
    try:
        seen: dict[str, set[str]] = {b.url: set() for b in boards}
        counts = dict.fromkeys(seen, 0)

        def handler(board: Board) -> Any:
            def on_sif(sif: SifReceived, now: float) -> None:
                seen[board.url].add(threading.current_thread().name)
                counts[board.url] += 1

            return on_sif

        for b in boards:
            b.on_sif(None, handler(b))
        assert len(reactor) == 3
        assert wait_for(lambda: all(c > 20 for c in counts.values()))
        # every board's samples arrive on the one loop thread, none on a thread of its own
        assert all(names == {"j2a:reactor"} for names in seen.values())
        # blocking calls from this thread (and concurrently from another) are answered
        results: list[bytes] = []
        t = threading.Thread(target=lambda: results.append(boards[1].call("a2jEcho", b"x").payload))
        t.start()
        assert boards[0].call("a2jEcho", b"hello").payload == b"hello"
        t.join(5)
        assert results == [b"x"]
    finally:
        for b in boards:
            b.close()
    assert len(reactor) == 0


def test_a_blocking_call_from_the_loop_raises_instead_of_deadlocking(
    serve: Serve, reactor: Reactor
) -> None:
    server = serve(make_sim("rate", seed=1, rate_hz=100.0), "tcp://127.0.0.1:0")
    board = _board(server.url, reactor)
    errors: list[BaseException] = []

    def on_sif(sif: SifReceived, now: float) -> None:
        if not errors:
            try:
                board.call("a2jEcho")
            except RuntimeError as e:
                errors.append(e)

    try:
        board.on_sif(None, on_sif)
        assert wait_for(lambda: bool(errors))
        assert "I/O loop" in str(errors[0])
        assert board.call("a2jEcho", b"still").payload == b"still"  # the loop goes on
    finally:
        board.close()


@pytest.mark.parametrize("shared", [True, False], ids=["shared-loop", "own-thread"])
def test_ticker_and_async_clock_exchange_run_on_the_reading_thread(
    serve: Serve, reactor: Reactor, shared: bool
) -> None:
    # On the shared loop (a socket) and on a board's own reader (the memory transport).
    server = serve("thesis", "tcp://127.0.0.1:0" if shared else "memory")
    board = Board(open_transport(server.url), timeout=2.0, reactor=reactor if shared else None)
    try:
        board.handshake()
        reader = "j2a:reactor" if shared else f"j2a:{board.url}"
        got: list[tuple[str, Exchange | BaseException]] = []
        ticks: list[float] = []
        state = {"due": 0.0}

        def tick(now: float) -> None:
            ticks.append(now)
            state["due"] = now + 0.02
            board.clock_exchange_async(
                lambda r: got.append((threading.current_thread().name, r)), timeout=1.0
            )

        board.link.set_ticker(lambda: state["due"], tick)
        assert wait_for(lambda: len(got) >= 5)
        board.link.set_ticker(None)
        names = {name for name, _ in got}
        assert names == {reader}
        for _, ex in got:
            assert isinstance(ex, Exchange)
            assert ex.t1 < ex.t4 and ex.t2 <= ex.t3
        assert all(b - a >= 0.02 for a, b in itertools.pairwise(ticks))
        n = len(ticks)
        assert board.call("a2jEcho", b"x").payload == b"x"
        assert len(ticks) == n  # removed: no more ticks
    finally:
        board.close()


def test_async_clock_exchange_reports_a_timeout_to_its_callback() -> None:
    # A board that never answers: the callback gets the CallTimeout, on the loop thread, when
    # the loop's clock says so (a fake one: 30 s in no real time).
    clock = FakeClock()
    reactor = Reactor(clock=clock).start()
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(1)
    url = f"tcp://127.0.0.1:{listener.getsockname()[1]}"
    board = Board(open_transport(url), timeout=0.2, reactor=reactor)
    conn, _ = listener.accept()
    try:
        assert board.clock is clock  # (a board read by the loop runs on the loop's clock)
        board.index = {"a2jClock": 3}
        done: Future[tuple[str, Exchange | BaseException]] = Future()
        board.clock_exchange_async(
            lambda got: done.set_result((threading.current_thread().name, got)), timeout=30.0
        )
        assert board.link.next_due == clock.monotonic() + 30.0
        clock.advance(30.0)
        thread, got = done.result(10)
        assert isinstance(got, CallTimeout) and thread == "j2a:reactor"
        assert not board.link.transport.count_arrivals  # counting ends with the exchange
    finally:
        board.close()
        conn.close()
        listener.close()
        reactor.stop()


def _settle(board: Board) -> None:
    """Two round trips: the thread that reads ``board`` has looked at its timers since this
    was called (the second reply is read after a pass that began after the first's)."""
    for _ in range(2):
        assert board.call("a2jEcho", b"s").payload == b"s"


@pytest.mark.parametrize("shared", [True, False], ids=["shared-loop", "own-thread"])
def test_a_ticker_runs_when_due_on_the_boards_clock_and_not_before(
    serve: Serve, shared: bool
) -> None:
    """Timers are on the board's clock: a ticker due in 1 s of a fake clock does not run while
    that clock stands 1 ms short, however long the machine takes, and runs at once, at its due
    time, when the clock gets there; on the shared loop and on a board's own reader."""
    clock = FakeClock()
    reactor = Reactor(clock=clock).start() if shared else None
    server = serve("thesis", "tcp://127.0.0.1:0" if shared else "memory")
    board = Board(open_transport(server.url), timeout=2.0, reactor=reactor, clock=clock)
    try:
        board.handshake()
        start = clock.monotonic()
        ticks: list[float] = []
        board.link.set_ticker(lambda: None if ticks else start + 1.0, ticks.append)
        assert board.link.next_due == start + 1.0
        clock.advance(0.999)
        _settle(board)
        assert ticks == []
        clock.advance(0.001)
        assert wait_for(lambda: bool(ticks))
        assert ticks == [start + 1.0]
    finally:
        board.close()
        if reactor is not None:
            reactor.stop()


def test_a_board_and_its_loop_share_one_clock() -> None:
    reactor = Reactor(clock=FakeClock()).start()
    with socket.socket() as listener:
        listener.bind(("127.0.0.1", 0))
        listener.listen(1)
        transport = open_transport(f"tcp://127.0.0.1:{listener.getsockname()[1]}")
        try:
            with pytest.raises(ValueError, match="one clock"):
                Board(transport, reactor=reactor, clock=FakeClock())
        finally:
            transport.close()
            reactor.stop()


# ---- the probe budget (pure: fakes for the session, daemon and board) -------------------------
class _FakeSession:
    """What the prober reports to: a plain holder, through the context's callables."""

    def __init__(self, boards: int, budget: float) -> None:
        self.spec = BoardSpec("tcp://127.0.0.1:1")
        self.name = "fake"
        self.error = ""
        self.rtt_us: float | None = None
        self.map_pushes = 0
        self.gap = boards / budget

    def context(self) -> ProbeContext:
        def push() -> None:
            self.map_pushes += 1

        return ProbeContext(
            name=self.name,
            timeout=self.spec.timeout,
            link_timeout=self.spec.link_timeout,
            byte_ns=self.spec.byte_ns,
            realtime_offset_ns=0,
            probe_gap=lambda: self.gap,
            on_rtt=lambda us: setattr(self, "rtt_us", us),
            on_error=lambda text: setattr(self, "error", text),
            on_map_pushed=push,
        )


class _FakeBoard:
    index: dict[str, int] = {"a2jClock": 0}

    def __init__(self) -> None:
        self.sent = 0
        self.clock = FakeClock()  # (the prober reads it for lost probes)
        self.link = self  # (its ticker's: reschedule)

    def clock_exchange_async(self, callback: Any, timeout: float, *, byte_ns: float) -> None:
        self.sent += 1

    def reschedule(self) -> None:
        pass


def test_probe_budget_rations_tracking_probes_but_not_bursts() -> None:
    session = _FakeSession(boards=50, budget=100.0)  # each board: at most every 0.5 s
    board = _FakeBoard()
    now = board.clock.monotonic()  # (the prober reads the board's clock for lost probes)
    sync = ClockSync(SyncOptions(), seed=1)
    sync.start(now)
    prober = ClockProber(session.context(), board, sync)  # type: ignore[arg-type]
    assert sync.state == BURST
    prober.tick(now)
    assert prober.due() is None  # one probe in flight at a time
    prober._on_reply(CallTimeout("fake", "a2jClock", "no reply"))  # lost
    assert sync.state == BURST and prober.due() == sync.due() < now + 0.5  # not rationed
    sync.state = TRACKING
    assert prober.due() == pytest.approx(now + 0.5)  # rationed: 50 boards / 100 per s
    prober.probe_now()  # a heartbeat is not rationed either
    assert prober.due() == 0.0
    assert board.sent == 1 and session.error == ""  # a timeout is the sync's business
