"""Hostile hosts and outages, continued from tests/test_hostile.py: the virtual board keeps its
replies when the host does not read, the fault relay's command line, errors that name the
board, and SIFs lost in an outage counted exactly past 256."""

from __future__ import annotations

import signal
import subprocess

import pytest

from missing_link.daemon.config import BoardSpec
from missing_link.daemon.session.status import SessionState
from missing_link.errors import BoardError
from missing_link.host.board import Board
from missing_link.topics import Update
from missing_link.virtual import make_sim
from missing_link.virtual.faults import FaultRelay

from .helpers import ML, ml, wait_for
from .test_hostile import Serve, daemon_for


# ---- the virtual board never drops a reply ----------------------------------------------------
def test_virtual_board_keeps_replies_when_the_host_does_not_read() -> None:
    import socket

    from missing_link.board.wire import encode_frame
    from missing_link.virtual.server import OUT_LIMIT, _Link

    a, b = socket.socketpair()
    a.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4096)
    link = _Link(a.fileno(), a)
    sif = encode_frame(0xED, 0, 1, bytes(200))
    for _ in range(2000):  # ~400 KiB of SIFs, nobody reading
        assert link.send(b"", [sif])
    reply = encode_frame(0x12, 7, 0xBA, b"hello")
    assert link.send(reply, [])
    assert link.dropped > 0 and link.queued <= OUT_LIMIT + len(reply)
    b.setblocking(False)
    received = b""
    for _ in range(1000):
        try:
            received += b.recv(1 << 20)
        except BlockingIOError:
            link.send(b"", [])
            if reply in received:
                break
    assert reply in received
    a.close()
    b.close()


@pytest.mark.slow
def test_relay_cli_forwards_and_reports(serve: Serve) -> None:
    server = serve("thesis", listen="tcp://127.0.0.1:0")
    p = subprocess.Popen(
        [*ML, "relay", server.url, "--delay-ms", "1", "--duration", "20"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert p.stdout is not None
        line = p.stdout.readline()
        assert line.startswith("LISTENING tcp://127.0.0.1:")
        with Board.open(line.split()[1]) as board:
            assert board.call("a2jEcho", b"x").payload == b"x"
    finally:
        p.send_signal(signal.SIGINT)
        _out, err = p.communicate(timeout=10)
    assert p.returncode == 0 and "forwarded" in err


@pytest.mark.slow
def test_relay_rejects_bad_arguments() -> None:
    r = ml("relay", "tcp://127.0.0.1:1", "--corrupt", "2")
    assert r.returncode == 2 and "probability" in r.stderr and "Traceback" not in r.stderr


def test_board_error_names_the_board(serve: Serve) -> None:
    server = serve(make_sim("hostile_res", seed=1))
    with pytest.raises(BoardError, match=r"res: property clock.res_us"):
        Board.open(server.url)


@pytest.mark.slow  # (seconds of real time)
def test_outage_losses_are_counted_exactly_past_256(serve: Serve) -> None:
    """An outage of thousands of SIFs: the 8-bit seq alone would count them modulo 256; the
    board's a2jSifCount makes the count exact."""
    server = serve(
        make_sim("rate", seed=1, name="fast", rate_hz=1000.0), listen="tcp://127.0.0.1:0"
    )
    with FaultRelay(server.url) as relay, daemon_for(BoardSpec(relay.url)) as d:
        assert d.wait_until_up(10)
        got: list[Update] = []
        d.subscribe("/fast/signal", got.append)
        assert wait_for(lambda: len(got) > 100, 15)
        relay.blackhole(True)
        assert wait_for(lambda: d.sessions[0].state != SessionState.UP, 15)
        relay.blackhole(False)
        n = len(got)
        assert wait_for(lambda: d.sessions[0].state == SessionState.UP and len(got) > n + 100, 15)
        (st,) = d.status()
    values = [u.values[0] for u in got]
    gaps = [(b - a - 1, u.lost) for a, b, u in zip(values, values[1:], got[1:], strict=False)]
    big = [(gap, lost) for gap, lost in gaps if gap > 0]
    assert big and all(gap == lost for gap, lost in big), big
    assert max(g for g, _ in big) > 256  # the outage really was past one wrap
    assert st["outage_lost_sifs"] >= max(g for g, _ in big)
