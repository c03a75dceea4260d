"""The host client against virtual boards: calls, blobs, SIFs, errors, threads, asyncio."""

from __future__ import annotations

import asyncio
import itertools
import struct
import threading
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import pytest

from missing_link import (
    AsyncBoard,
    Board,
    CallError,
    CallTimeout,
    FunctionFailed,
    LinkLost,
    UnknownFunction,
    open_board,
)
from missing_link.j2a import SifReceived
from missing_link.testing import FakeClock
from missing_link.transport.in_process import memory_pair

from .helpers import wait_for

Serve = Any


def test_open_reads_description(serve: Serve) -> None:
    server = serve("thesis")
    with open_board(server.url) as board:
        assert board.functions[:2] == ["a2jGetMapping", "a2jMany"]
        assert {"a2jGetTransds", "a2jClock", "getTime", "setTrigger", "a2j_set_servo"} <= set(
            board.functions
        )
        assert board.properties["j2a.version"] == "2" and not board.is_original
        assert [t.name for t in board.transducers or []] == [
            "quad",
            "dist_ir",
            "dist_us",
            "servo",
            "trigger",
        ]
        assert board.call("a2jEcho", b"abc").payload == b"abc"
        big = bytes(range(256)) * 3
        assert board.write_many("a2jEchoMany", big[:249]) == 0xBE


def test_original_board_functions_and_properties(serve: Serve) -> None:
    server = serve("original")
    progress: list[tuple[int, int | None]] = []
    with open_board(server.url) as board:
        assert board.is_original and board.transducers is None
        assert board.functions[6:] == ["getTime", "syncTime", "bigBlob"]
        # the 2014 firmware's a2jMany cannot move a blob over 498 bytes (its offset bug): the
        # read stops before the first chunk past offset 255, naming it (issue 23, item 7)
        with pytest.raises(CallError, match="offset bug"):
            board.read_many("bigBlob", progress=lambda done, total: progress.append((done, total)))
        assert progress == [(249, None)]


def test_unknown_function_names_board_and_choices(serve: Serve) -> None:
    server = serve("thesis")
    with open_board(server.url) as board, pytest.raises(UnknownFunction) as err:
        board.call("setServo")
    assert "thesis: board has no function 'setServo'" in str(err.value)
    assert "a2j_set_servo" in str(err.value)


def test_function_failed_carries_code(serve: Serve) -> None:
    server = serve("thesis")
    with open_board(server.url) as board, pytest.raises(FunctionFailed) as err:
        board.call_ok("a2j_set_servo", b"\x80")  # -128 is N/A: the servo refuses it
    assert err.value.code == 0xFF and "a2j_set_servo returned 0xff" in str(err.value)


def test_a_timeout_runs_on_the_boards_clock_names_the_function_and_leaves_no_lock() -> None:
    """A call's deadline is on the board's clock: 30 s of a fake clock pass in no real time,
    and not before it is moved; the timeout names the function, and the link takes the next
    call (nothing left locked)."""
    clock = FakeClock()
    host, _silent = memory_pair("silent")
    board = Board(host, timeout=30.0, clock=clock)
    try:
        with ThreadPoolExecutor(1) as pool:
            for _ in range(2):
                start = clock.monotonic()
                call = pool.submit(board.call_index, 0, b"", "a2jGetMapping")
                assert wait_for(lambda: board.link.next_due is not None)  # the call is out
                assert board.link.next_due == start + 30.0  # the deadline, on the fake clock
                clock.advance(30.0)
                with pytest.raises(CallTimeout) as err:
                    call.result(10)
                assert "a2jGetMapping: no reply within 30000 ms" in str(err.value)
        assert board.link_stats().timeouts == 2
    finally:
        board.close()
    assert not board.alive


def test_the_handshake_asks_again_until_its_deadline_on_the_boards_clock() -> None:
    """First contact is asked again after each timeout (a board still booting) until the
    handshake's deadline, all on the board's clock: the last ask waits only what is left."""
    clock = FakeClock()
    host, _mute = memory_pair("mute")
    board = Board(host, timeout=1.0, clock=clock)
    try:
        with ThreadPoolExecutor(1) as pool:
            done = pool.submit(board.handshake, deadline=clock.monotonic() + 3.5)
            for asked in range(1, 5):  # at 0, 1, 2 and 3 s; the last for 0.5 s
                assert wait_for(lambda: board.link_stats().requests == asked)  # noqa: B023
                assert board.link.next_due == clock.monotonic() + (1.0 if asked < 4 else 0.5)
                clock.advance(1.0)
            with pytest.raises(CallTimeout, match=r"handshake not done within 3\.5 s"):
                done.result(10)
        assert board.link_stats().requests == 4
    finally:
        board.close()


def test_last_frame_is_on_the_boards_clock(serve: Serve) -> None:
    """``last_frame`` (a link's staleness, what the daemon's supervisor watches) is stamped on
    the board's clock: a silent board goes stale as the fake clock moves, and a reply is fresh."""
    from missing_link.board.runtime import BoardRuntime

    clock = FakeClock()
    server = serve(BoardRuntime("quiet", "m", "s", epoch="e"))  # no transducers: no SIFs
    with open_board(server.url, clock=clock) as board:
        assert board.last_frame == clock.monotonic()  # the handshake's replies, just now
        clock.advance(7.5)
        assert clock.monotonic() - board.last_frame == 7.5
        assert board.call("a2jEcho", b"x").payload == b"x"
        assert board.last_frame == clock.monotonic()


def test_link_broken_vs_closed(serve: Serve) -> None:
    host, dev = memory_pair("flaky")
    board = Board(host, timeout=5.0)
    result: list[BaseException] = []

    def waiter() -> None:
        try:
            board.call_index(4, b"", "a2jEcho")
        except BaseException as e:  # noqa: BLE001 - the test inspects whatever was raised
            result.append(e)

    t = threading.Thread(target=waiter)
    t.start()
    assert wait_for(lambda: board.link.calls_waiting)
    dev.close()  # the board end goes away while the call waits
    t.join(5)
    assert isinstance(result[0], LinkLost) and result[0].broken
    assert "other side closed" in str(result[0])
    board.close()
    with pytest.raises(LinkLost) as err:
        board.call_index(4, b"", "a2jEcho")
    assert err.value.broken  # it broke before we closed it: the first cause is kept
    assert not board.alive


def test_closed_board_reports_closed_not_broken(serve: Serve) -> None:
    server = serve("thesis")
    board = open_board(server.url)
    board.close()
    with pytest.raises(LinkLost) as err:
        board.call("a2jEcho")
    assert err.value.broken is False


def test_sif_handlers_by_cmd_and_any(serve: Serve) -> None:
    server = serve("thesis")
    got: dict[str, list[SifReceived]] = {"quad": [], "any": []}
    done = threading.Event()
    with open_board(server.url) as board:
        board.on_sif(0, lambda ev, now: got["quad"].append(ev))

        def any_sif(ev: SifReceived, now: float) -> None:
            got["any"].append(ev)
            if len(got["any"]) > 50:
                done.set()

        board.on_sif(None, any_sif)
        assert done.wait(5)
        assert {e.cmd for e in got["quad"]} == {0}
        seqs = [e.seq for e in got["any"][:40]]
        assert all((b - a) & 0xFF == 1 for a, b in itertools.pairwise(seqs))


def test_sifs_before_anything_listens_are_counted(serve: Serve) -> None:
    """A board streams from its boot; the host listens once its handshake is done: what came
    before is counted (``unheard_sifs``, the status's ``unheard_sifs``), not silently gone."""
    server = serve("thesis")
    with open_board(server.url) as board:
        assert wait_for(lambda: board.link_stats().unheard_sifs > 0, 5)
        done = threading.Event()
        board.on_sif(None, lambda ev, now: done.set())
        assert done.wait(5)
        before = board.link_stats().unheard_sifs
        assert board.link_stats().sifs >= before  # (of the SIFs the link decoded)
        board.call("a2jEcho")
        assert board.link_stats().unheard_sifs == before  # (a listener now hears every one)


def test_handler_exception_does_not_stop_board(serve: Serve) -> None:
    server = serve("thesis")
    raised = []

    def failing(ev: SifReceived, now: float) -> None:
        raised.append(ev)
        raise ZeroDivisionError("a handler's bug")

    with open_board(server.url) as board:
        board.on_sif(None, failing)
        assert wait_for(lambda: len(raised) >= 5)  # it raised, and SIFs kept coming
        assert board.call("a2jEcho", b"x").payload == b"x"


def test_asyncio_api(serve: Serve) -> None:
    server = serve("thesis")

    async def main() -> tuple[bytes, int, int]:
        async with await AsyncBoard.open(server.url) as board:
            queue = board.sifs(cmd=1)
            echo = await board.call("a2jEcho", b"async")
            results = await asyncio.gather(*(board.call("getTime") for _ in range(5)))
            stamps = [struct.unpack("<Q", r.payload)[0] for r in results]
            sif, _now = await asyncio.wait_for(queue.get(), 5)
            return echo.payload, sif.cmd, len(set(stamps))

    payload, cmd, distinct = asyncio.run(main())
    assert payload == b"async" and cmd == 1 and distinct == 5


def test_many_boards_one_broken_does_not_affect_other(serve: Serve) -> None:
    a = serve("thesis")
    b = serve("rangers")
    with open_board(a.url) as ba, open_board(b.url) as bb:
        b.stop()
        assert wait_for(lambda: not bb.alive)
        assert ba.call("a2jEcho", b"still").payload == b"still"
        with pytest.raises(LinkLost):
            bb.call("a2jEcho", b"gone", timeout=0.5)


def test_mapping_longer_than_one_frame_is_read_in_full(serve: Serve) -> None:
    from missing_link.board.runtime import BoardRuntime

    rt = BoardRuntime("long", "m", "s", epoch="e")
    for i in range(30):
        rt.add_function(f"function_with_a_long_name_{i:02d}", lambda p: (0, b""))
    server = serve(rt)
    with open_board(server.url) as board:
        assert len(board.functions) == 41  # 11 built-ins + 30
        assert board.functions[-1] == "function_with_a_long_name_29"
        assert board.call("function_with_a_long_name_29").code == 0


def test_a_call_times_out_on_time_while_the_reader_idles() -> None:
    """An idle reader waits up to a second in select(); a new call with a shorter timeout pokes
    it, so the timeout fires when due, not when the idle wait ends."""
    import socket
    import time

    from missing_link.errors import CallTimeout
    from missing_link.transport import open_transport

    with socket.socket() as srv:
        srv.bind(("127.0.0.1", 0))
        srv.listen(1)
        url = f"tcp://127.0.0.1:{srv.getsockname()[1]}"
        board = Board(open_transport(url))  # a peer that never answers
        conn, _ = srv.accept()
        try:
            time.sleep(0.05)  # the reader is in its 1 s idle wait by now
            t0 = time.monotonic()
            with pytest.raises(CallTimeout):
                board.call_index(0, b"", "a2jGetMapping", timeout=0.1)
            assert time.monotonic() - t0 < 0.5  # not the rest of the 1 s idle wait
        finally:
            board.close()
            conn.close()


def test_link_stats_are_a_snapshot_of_the_links_counters(serve: Serve) -> None:
    server = serve("thesis")
    with open_board(server.url) as board:
        before = board.link_stats()
        assert board.call("a2jEcho", b"x").payload == b"x"
        after = board.link_stats()
        assert after.requests == before.requests + 1 and after.replies == before.replies + 1
        assert after.frames > before.frames and after.bad_checksums == 0
        assert after.transport == {}  # (a memory link counts nothing of its own)
        board.link.count_lost_sifs(512)  # two whole seq wraps, known from the board's count
        assert board.link_stats().lost_sifs >= after.lost_sifs + 512
        assert before.requests == board.link_stats().requests - 1  # a snapshot: it stayed
