"""Boards that dial in, attacked (issue 43.3, 43.4, 43.9): idle connections that take every place
the listener greets in, an impostor that dials first under a configured board's name, and a
thousand ids that dial once and leave.  Each: the real board still gets in, under its own name,
and what the others leave behind is bounded."""

from __future__ import annotations

import os
import selectors
import socket
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from missing_link.daemon import Daemon
from missing_link.daemon.config import parse_config
from missing_link.daemon.intake.listener import (
    FIRST_REPLY_S,
    GRACE_S,
    MAX_PENDING,
    PER_ADDRESS,
    Listener,
    ListenerContext,
)
from missing_link.daemon.listen_spec import parse_listen
from missing_link.testing.clock import FakeClock
from missing_link.virtual import make_sim
from missing_link.virtual.server import BoardServer

from .helpers import wait_for


def listening(doc: dict[str, Any] | None = None) -> Daemon:
    cfg = parse_config(doc or {})
    cfg.listen = "tcp://127.0.0.1:0"
    return Daemon(cfg)


@contextmanager
def dialing(port: int, **sim: Any) -> Iterator[BoardServer]:
    """A virtual board (the rangers) that dials the daemon on ``port``, until the block ends."""
    server = BoardServer(make_sim("rangers", **sim), f"tcp://127.0.0.1:{port}", dial=True)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield server
    finally:
        server.stop()
        thread.join(5)


def _up(d: Daemon) -> int:
    return sum(s.state == "up" for s in d.sessions)


class Squatter:
    """``n`` idle connections to ``port`` from ``source`` (another loopback address: another
    machine on the network, as far as the listener can tell), each opened again the moment the
    daemon closes it (a select on all of them): as many places as the listener lets it have,
    held for as long as this lasts."""

    def __init__(self, port: int, n: int, source: str = "127.0.0.2") -> None:
        self.port, self.n, self.source = port, n, source
        self.opened = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _open(self, sel: selectors.BaseSelector) -> None:
        s = socket.create_connection(("127.0.0.1", self.port), source_address=(self.source, 0))
        sel.register(s, selectors.EVENT_READ)
        self.opened += 1

    def _run(self) -> None:
        with selectors.DefaultSelector() as sel:
            for _ in range(self.n):
                self._open(sel)
            while not self._stop.is_set():
                for key, _ in sel.select(0.05):
                    s: Any = key.fileobj
                    try:
                        data = s.recv(4096)  # (the daemon's requests: never answered)
                    except OSError:
                        data = b""
                    if not data:
                        sel.unregister(s)
                        s.close()
                        self._open(sel)
            for key in list(sel.get_map().values()):
                key.fileobj.close()  # type: ignore[union-attr]

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5)


def test_connections_from_another_address_keep_no_board_out() -> None:
    """(issue 43.9: eight idle connections, opened again as the daemon closed them, kept a
    real board out of the listener for as long as they lasted; now one address holds at most
    PER_ADDRESS places)"""
    with listening() as d:
        assert d.dialins is not None
        squat = Squatter(d.dialins.listener.port, MAX_PENDING)
        try:
            assert wait_for(lambda: d.dialins.status()["accepted"] >= PER_ADDRESS, 5)  # type: ignore[union-attr]
            with dialing(d.dialins.listener.port, seed=2):
                assert wait_for(lambda: d.sessions and d.wait_until_up(0.1), 10), d.dialins.status()
            kinds = d.dialins.status()["refused_kinds"]
        finally:
            squat.close()
    assert "busy" in kinds, kinds  # (the squatter's fifth and later: refused, not the board)
    assert d.sessions[0].name == "board_b"


def test_idle_connections_from_the_boards_own_address_give_their_places_up() -> None:
    """Eight connections from the board's own address that say nothing: past GRACE_S a
    newcomer takes the place of the oldest (and past FIRST_REPLY_S each is closed): the board
    gets in at its first dial (before: when the daemon gave up on them, 5 s on)."""
    with listening() as d:
        assert d.dialins is not None
        port = d.dialins.listener.port
        held = [socket.create_connection(("127.0.0.1", port)) for _ in range(MAX_PENDING)]
        try:  # (one address: PER_ADDRESS of them greeted, the rest refused at once)
            assert wait_for(lambda: "busy x4" in d.dialins.status()["refused_kinds"], 5)  # type: ignore[union-attr]
            time.sleep(GRACE_S)  # (the scenario: they have had their time to answer)
            with dialing(port, seed=2):
                assert wait_for(lambda: d.sessions and d.wait_until_up(0.1), 10), d.dialins.status()
            st = d.dialins.status()
        finally:
            for s in held:
                s.close()
    assert st["accepted"] == PER_ADDRESS + 1 and "busy x4," in st["refused_kinds"], st
    # its first dial took an idle one's place (or, on a slow machine, they were closed first)
    assert "evicted x1" in st["refused_kinds"] or "silent x4" in st["refused_kinds"], st


def test_a_configured_name_belongs_to_its_configured_id() -> None:
    """(issue 43.3: a board of another id that dialed in first and called itself ``board_b``
    took the configured name, and the real board published as ``board_b_2``)"""
    with listening({"boards": {"board_b": {"id": "real-b-1"}}}) as d:
        assert d.dialins is not None
        port = d.dialins.listener.port
        with dialing(port, seed=3, board_id="impostor-9"):  # board.name "board_b", another id
            assert wait_for(lambda: d.sessions and d.wait_until_up(0.1), 10)
            (impostor,) = d.sessions
            assert impostor.name == "board_b_2", impostor.name
            assert any("belongs to board.id 'real-b-1'" in w for w in impostor.warnings)
            with dialing(port, seed=4, board_id="real-b-1"):
                assert wait_for(lambda: len(d.sessions) == 2 and d.wait_until_up(0.1), 10)
                real = next(s for s in d.sessions if s is not impostor)
                assert real.name == "board_b" and not real.warnings, real.warnings


def test_unknown_ids_that_left_expire_and_are_capped() -> None:
    """(issue 43.4: 1,000 ids that dialed once and left kept 1,008 threads, 143 MB and a third
    of a core; bench/bench_dialin.py measures it).  A board of an id the config does not name
    is forgotten dialin_expire s after it left; at most dialin_max are held; a configured id
    is kept for good."""
    doc = {"daemon": {"dialin_expire": 0.3, "dialin_max": 2, "diagnostics_period": 0.05},
           "boards": {"kept": {"id": "known-1"}}}  # fmt: skip
    with listening(doc) as d:
        assert d.dialins is not None
        port = d.dialins.listener.port
        with dialing(port, seed=5, board_id="known-1", name="kept"):
            assert wait_for(lambda: len(d.sessions) == 1 and d.wait_until_up(0.1), 10)
        with dialing(port, seed=6, board_id="u-1"), dialing(port, seed=7, board_id="u-2"):
            assert wait_for(lambda: _up(d) == 2 and len(d.sessions) == 3, 10), d.status()
            with dialing(port, seed=8, board_id="u-3"):  # a third unknown id: refused
                assert wait_for(lambda: "refused x" in d.dialins.status()["refused_kinds"], 10)  # type: ignore[union-attr]
            threads = len(threading.enumerate())
        # the two unknown boards left: their sessions go, the configured one's stays
        assert wait_for(lambda: [s.name for s in d.sessions] == ["kept"], 10), d.status()
        assert d.dialins.status()["expired"] == 2 and d.dialins.status()["unknown_ids"] == 0
        assert len(threading.enumerate()) < threads  # (their supervisors ended)
        with dialing(port, seed=8, board_id="u-3"):  # room again
            assert wait_for(lambda: _up(d) == 1 and len(d.sessions) == 2, 10), d.status()


def _counted(kinds: str, *names: str) -> int:
    """How many of ``refused_kinds`` ("busy x3, silent x1") are of these kinds."""
    got = dict(k.rsplit(" x", 1) for k in kinds.split(", ") if k)
    return sum(int(got.get(n, 0)) for n in names)


def test_a_flood_of_clients_costs_the_listener_nothing_it_keeps() -> None:
    """Clients that connect and say nothing or junk: at most PER_ADDRESS from one address are
    greeted at once (MAX_PENDING in all), the rest closed at once; all counted by kind; a board
    that dials afterwards gets in."""
    from missing_link.daemon.intake.listener import MAX_PENDING, PER_ADDRESS

    with listening() as d:
        assert d.dialins is not None
        port = d.dialins.listener.port
        held = [socket.create_connection(("127.0.0.1", port)) for _ in range(MAX_PENDING + 3)]
        held[0].sendall(os.urandom(300))
        try:
            st = d.dialins.status
            n = MAX_PENDING + 3
            assert wait_for(lambda: st()["accepted"] + _counted(st()["refused_kinds"], "busy") == n)
            assert st()["accepted"] >= PER_ADDRESS and st()["greeting"] <= PER_ADDRESS, st()
        finally:
            for s in held:
                s.close()
        kinds = lambda: d.dialins.status()["refused_kinds"]  # type: ignore[union-attr]  # noqa: E731
        accepted = d.dialins.status()["accepted"]
        gone = ("handshake failed", "silent", "evicted")
        assert wait_for(lambda: _counted(kinds(), *gone) == accepted, 20), kinds()
        with dialing(port, seed=2):
            assert wait_for(lambda: d.sessions and d.wait_until_up(0.1), 20), d.status()
            assert d.dialins.status()["errors"] == 0 and d.sessions[0].name == "board_b"


def test_a_silent_greeting_is_closed_on_the_daemons_clock() -> None:
    """(issue 42.2: the listener's grace and first-reply deadline are on the clock it is
    handed, the daemon's, not on time.monotonic) A connection that never answers stays open
    while the fake clock stands still, however long that is in real time, and is closed as
    soon as the fake clock passes FIRST_REPLY_S."""
    clock = FakeClock()
    listener = Listener(parse_listen("tcp://127.0.0.1:0"), clock)
    # (the handshake's own deadline far off: only the listener's first-reply rule can close it)
    listener.start(ListenerContext(None, 60.0, 600.0, lambda board: "not wanted"))
    try:
        silent = socket.create_connection(("127.0.0.1", listener.port))
        silent.settimeout(10)
        assert wait_for(lambda: listener.status()["greeting"] == 1, 5), listener.status()
        request = silent.recv(4096)  # (the greeting's first request: never answered)
        assert request
        # longer than FIRST_REPLY_S in real time (on time.monotonic it would be closed by now),
        # not yet on its clock
        time.sleep(FIRST_REPLY_S + 0.5)
        assert listener.status()["greeting"] == 1 and not listener.refused, listener.status()
        clock.advance(FIRST_REPLY_S + 0.1)
        assert wait_for(lambda: listener.refused.get("silent") == 1, 5), listener.status()
        while silent.recv(4096):  # (the daemon's later requests, then its end)
            pass
        silent.close()
    finally:
        listener.stop()
