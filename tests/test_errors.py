"""No error vanishes, and every error is in one tree (issue 33, items 3 and 5).

Where an exception is caught so that a thread goes on (a publisher's encoder, the I/O loop, a
board's SIF handler, the session's supervisor, a bus subscriber, the control endpoint), it is
counted by kind, logged once with its traceback, and shown in the status and on
``/diagnostics``.  Each test injects one such exception into the real component (a real
daemon, reactor, board or endpoint; the fault is a small fake: an encoder, a link, a handler
that raises) and finds it counted and shown."""

from __future__ import annotations

import json
import logging
import socket
import threading
from pathlib import Path
from typing import Any

from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config
from missing_link.daemon.control.endpoint import ControlServer, ask
from missing_link.daemon.session.inflight import InFlight
from missing_link.daemon.session.session import BoardSession
from missing_link.daemon.session.status import SessionState
from missing_link.errors import TransportBroken
from missing_link.host.board import Board
from missing_link.host.reactor import Reactor
from missing_link.logs import MAX_KINDS, OTHER, ErrorCounts
from missing_link.publishers.base import Publisher
from missing_link.publishers.zenoh import data_key
from missing_link.topics import Update
from missing_link.transport import open_transport
from missing_link.virtual import make_sim

from .helpers import free_port, wait_for
from .test_daemon_parts import PlainContext

log = logging.getLogger("missing_link.test")


def raised(exc: BaseException) -> BaseException:
    try:
        raise exc
    except BaseException as e:  # noqa: BLE001 - (a traceback to count)
        return e


def tracebacks(caplog: Any, kind: str) -> list[logging.LogRecord]:
    """The log records that said ``kind`` with its traceback."""
    return [r for r in caplog.records if kind in r.getMessage() and r.exc_info]


# ---- the counter -------------------------------------------------------------------------------
def test_errors_are_counted_by_kind_and_each_kind_is_said_once(caplog: Any) -> None:
    faults = ErrorCounts(log, "thing")
    assert faults.to_json() == {"errors": 0, "error_kinds": ""}
    with caplog.at_level(logging.ERROR):
        for k in range(5):
            faults.caught("publish", raised(ValueError(f"bad value {k}")))
        faults.caught("publish", raised(KeyError("x")))
        faults.caught("tick", raised(ValueError("late")))
    assert faults.total == 7
    kinds = {k.kind: k for k in faults.kinds()}
    assert set(kinds) == {"ValueError in publish", "KeyError in publish", "ValueError in tick"}
    first = kinds["ValueError in publish"]
    assert first.count == 5 and first.first.startswith("bad value 0 at test_errors.py:")
    assert "ValueError: bad value 0" in first.traceback  # the first one's, kept
    said = [r for r in caplog.records if r.name == "missing_link.test"]
    assert len(said) == 3 and all(r.exc_info for r in said)  # one per kind, with its traceback
    assert said[0].getMessage().startswith("thing: publish failed (ValueError in publish")
    summary = faults.to_json()["error_kinds"]
    assert summary.startswith("ValueError in publish x5 (bad value 0 at test_errors.py:")


def test_kinds_are_bounded(caplog: Any) -> None:
    faults = ErrorCounts(log)
    kinds = [type(f"E{k}", (Exception,), {}) for k in range(MAX_KINDS + 10)]
    with caplog.at_level(logging.ERROR):
        for cls in kinds:
            faults.caught("x", raised(cls("?")))
    assert faults.total == MAX_KINDS + 10
    counted = {k.kind: k.count for k in faults.kinds()}
    assert len(counted) == MAX_KINDS + 1 and counted[OTHER] == 10


def test_counting_is_safe_from_many_threads() -> None:
    faults = ErrorCounts(logging.getLogger("missing_link.test.quiet"))
    logging.getLogger("missing_link.test.quiet").disabled = True
    e = raised(RuntimeError("x"))

    def hammer() -> None:
        for _ in range(2000):
            faults.caught("loop", e)

    threads = [threading.Thread(target=hammer) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert faults.total == 8000 and faults.kinds()[0].count == 8000


# ---- a publisher whose encoder raises: an error, not a drop -----------------------------------
class BrokenEncoder:
    """An encoder with a bug: what a wrong CDR layout would do."""

    def encode(self, host_ns: list[int], values: list[Any]) -> bytes:
        raise struct_error("required argument is not an integer")


def struct_error(text: str) -> Exception:
    import struct

    return struct.error(text)


def test_an_encoder_that_raises_is_counted_by_kind_on_diagnostics(serve: Any, caplog: Any) -> None:
    """Zenoh computed the encoding inside ``except Exception: dropped += 1``: an encoder bug
    was a silent drop.  Now it is ``errors`` and ``error_kinds`` in the publisher's status and
    on ``/diagnostics``, its traceback logged once, and ``dropped`` stays for the transport."""
    import zenoh
    from rosbags.typesys import Stores, get_typestore

    server = serve("thesis", "tcp://127.0.0.1:0")
    port = free_port()
    cfg = Config(
        boards=[BoardSpec(server.url)],
        publishers=["bus", "zenoh"],
        publisher_options={"zenoh": {"listen": [f"tcp/127.0.0.1:{port}"], "connect": []}},
        diagnostics_period=0.2,
    )
    diags: list[bytes] = []
    with caplog.at_level(logging.ERROR), Daemon(cfg) as d:
        assert d.wait_until_up(10)
        zp = next(p for p in d.publishers if p.name == "zenoh")
        diag_type = "diagnostic_msgs/msg/DiagnosticArray"
        diag_key = data_key(0, "/diagnostics", diag_type, zp.typestore.hash_rihs01(diag_type))  # type: ignore[attr-defined]
        zcfg = zenoh.Config()
        zcfg.insert_json5("mode", json.dumps("peer"))
        zcfg.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
        zcfg.insert_json5("scouting/multicast/enabled", "false")
        with zenoh.open(zcfg) as client:
            sub = client.declare_subscriber(diag_key, lambda s: diags.append(bytes(s.payload)))
            quad = next(t for t in d.sessions[0].topics.values() if t.name == "/thesis/quad")
            quad.encoder = BrokenEncoder()  # type: ignore[assignment]
            assert wait_for(lambda: zp.faults.total >= 3)
            st = next(s for s in d.publisher_status() if s["publisher"] == "zenoh")
            seen = len(diags)
            assert wait_for(lambda: len(diags) >= seen + 2)  # a /diagnostics round after it
            sub.undeclare()
        assert d.publish_errors >= st["errors"]
    assert st["errors"] >= 3 and st["dropped"] == 0, st
    assert st["error_kinds"].startswith("error in publish x"), st  # (struct.error)
    assert "encode" in st["error_kinds"] and st["level"] == 1
    assert len(tracebacks(caplog, "error in publish")) == 1  # said once, then only counted
    ts = get_typestore(Stores.ROS2_JAZZY)
    last = ts.deserialize_cdr(diags[-1], "diagnostic_msgs/msg/DiagnosticArray")
    mine = next(s for s in last.status if s.name == "missing_link publisher: zenoh")
    values = {kv.key: kv.value for kv in mine.values}
    assert int(values["errors"]) >= 3 and "error in publish" in values["error_kinds"]


# ---- the reactor: a board whose step raises ----------------------------------------------------
class Port:
    """A descriptor the loop reads: one end of a socket pair."""

    def __init__(self) -> None:
        self.mine, self.theirs = socket.socketpair()
        self.mine.setblocking(False)
        self.count_arrivals = False
        self.arrived_raises = False

    def fileno(self) -> int:
        return self.mine.fileno()

    def count_arrived(self, woke_ns: int = 0) -> None:
        if self.arrived_raises:
            raise RuntimeError("a bug counting arrivals")

    def read_ready(self) -> tuple[bytes, int, int]:
        return self.mine.recv(4096), 0, 0

    def close(self) -> None:
        self.mine.close()
        self.theirs.close()


class Link:
    """A link engine whose ``step`` raises once ``broken`` (a bug in one board's path)."""

    def __init__(self, url: str, broken: bool) -> None:
        self.url, self.broken = url, broken
        self.next_due: float | None = None
        self.faults = ErrorCounts(log, url)
        self.stepped = 0
        self.ended: list[BaseException | None] = []

    @property
    def calls_waiting(self) -> bool:
        return False

    def step(self, data: bytes, now_ns: int, rx_ns: int = 0, first_rx_ns: int = 0) -> int:
        self.stepped += 1
        if self.broken:
            raise ZeroDivisionError("a bug decoding")
        return 1

    def tick(self, now: float) -> None:
        pass

    def finish(self, error: BaseException | None) -> None:
        self.ended.append(error)


def test_a_board_whose_step_raises_is_counted_and_ended_the_others_go_on(caplog: Any) -> None:
    reactor = Reactor().start()
    good, bad = Link("fake://good", False), Link("fake://bad", True)
    ports = [Port(), Port()]
    try:
        with caplog.at_level(logging.ERROR):
            reactor.add(good, ports[0])
            reactor.add(bad, ports[1])
            ports[1].theirs.send(b"x")
            assert wait_for(lambda: bool(bad.ended))
            for k in range(3):
                ports[0].theirs.send(b"y")
                assert wait_for(lambda k=k: good.stepped > k)  # type: ignore[misc]
        assert bad.faults.total == 1 and bad.faults.kinds()[0].kind == "ZeroDivisionError in step"
        assert isinstance(bad.ended[0], TransportBroken)  # its link ends, as broken
        assert good.faults.total == 0 and not good.ended and reactor.loop_errors == 0
        assert len(tracebacks(caplog, "ZeroDivisionError in step")) == 1
    finally:
        reactor.stop()
        for p in ports:
            p.close()


def test_a_bug_in_the_loop_itself_is_counted_and_shown_by_the_daemon(caplog: Any) -> None:
    """``Reactor.loop_errors`` was counted and read nowhere."""
    with caplog.at_level(logging.ERROR), Daemon(Config()) as d:
        link, port = Link("fake://loop", False), Port()
        port.count_arrivals = port.arrived_raises = True
        d.reactor.add(link, port)
        port.theirs.send(b"x")
        assert wait_for(lambda: d.reactor.loop_errors >= 2)  # (ready again every round)
        d.reactor.remove(link)
        lines = {s["publisher"]: s for s in d.publisher_status()}
        port.close()
    shown = lines["reactor"]
    assert shown["errors"] >= 2 and shown["level"] == 1
    assert shown["error_kinds"].startswith("RuntimeError in round x")
    assert "a bug counting arrivals" in shown["error_kinds"]
    assert len(tracebacks(caplog, "RuntimeError in round")) == 1


# ---- a board's session: its reading thread and its supervisor ----------------------------------
def test_a_sif_handler_that_raises_is_counted_in_the_session_status(
    serve: Any, caplog: Any
) -> None:
    """A bug on the sample path (here: what it hands on raises) is caught on the board's
    reading thread; it was logged with a traceback for every SIF and counted nowhere."""
    server = serve(make_sim("thesis", seed=3, name="thesis"))
    plain = PlainContext()

    def publish(update: Update) -> None:
        raise AttributeError("a bug on the sample path")

    plain.publish = publish  # type: ignore[method-assign]  # (its faces publish so)
    session = BoardSession(plain.build(), BoardSpec(server.url))
    with caplog.at_level(logging.ERROR):
        session.start()
        try:
            assert wait_for(lambda: session.state == SessionState.UP and session.faults.total >= 5)
            st = session.status()
        finally:
            session.stop(2.0)
    assert st["errors"] >= 5 and st["error_kinds"].startswith("AttributeError in SIF handler x")
    assert "a bug on the sample path" in st["error_kinds"]
    assert st["level"] == 1 and "errors caught" in st["message"]
    assert len(tracebacks(caplog, "AttributeError in SIF handler")) == 1


def test_a_bug_in_the_supervisor_is_counted_said_once_and_retried(serve: Any, caplog: Any) -> None:
    server = serve(make_sim("thesis", seed=3, name="thesis"))
    plain = PlainContext()

    def claim_type(board: str, t: Any) -> tuple[str, str | None]:
        raise KeyError("a bug in the claims")

    plain.type = claim_type  # type: ignore[method-assign]  # (its claims claim types so)
    session = BoardSession(plain.build(), BoardSpec(server.url))
    with caplog.at_level(logging.WARNING):
        session.start()
        try:
            assert wait_for(lambda: session.failures >= 3)
            st = session.status()
        finally:
            session.stop(2.0)
    assert st["error"].startswith("internal error: KeyError") and st["state"] != "up"
    assert st["errors"] >= 3 and st["error_kinds"].startswith("KeyError in session x")
    assert len(tracebacks(caplog, "KeyError in session")) == 1  # not once per retry


def test_a_reply_handler_that_raises_is_counted_on_the_board(serve: Any, caplog: Any) -> None:
    """An ``InFlight`` reply callback runs on the reading thread: its bug was logged and lost."""
    server = serve(make_sim("thesis", seed=3, name="thesis"))
    board = Board(open_transport(server.url), timeout=2.0)
    try:
        board.handshake()
        done = threading.Event()

        def on_reply(result: Any) -> None:
            done.set()
            raise IndexError("a bug reading the reply")

        echo = InFlight("a2jEcho", on_reply)
        with caplog.at_level(logging.ERROR):
            assert echo.start(board, b"hi", 2.0)
            assert done.wait(5) and wait_for(lambda: board.link.faults.total == 1)
            assert wait_for(lambda: not echo.busy)
            assert echo.start(board, b"again", 2.0)  # the slot is free again
            assert wait_for(lambda: board.link.faults.total == 2)
    finally:
        board.close()
    (kind,) = board.link.faults.kinds()
    assert kind.kind == "IndexError in a2jEcho reply" and kind.count == 2
    assert len(tracebacks(caplog, "IndexError in a2jEcho reply")) == 1


# ---- the bus: a subscriber callback that raises ------------------------------------------------
def test_a_bus_subscriber_that_raises_is_counted_by_kind(serve: Any, caplog: Any) -> None:
    server = serve(make_sim("thesis", seed=3, name="thesis"))
    with caplog.at_level(logging.ERROR), Daemon(Config(boards=[BoardSpec(server.url)])) as d:
        assert d.wait_until_up(10)

        def inline(update: Update) -> None:
            raise ValueError("an application's bug")

        def queued(update: Update) -> None:
            raise TypeError("another")

        d.subscribe("/thesis/quad", inline, queue=0)  # on the reading thread itself
        d.subscribe("/thesis/*", queued)  # on a thread of its own

        def bus() -> dict[str, Any]:
            return next(s for s in d.publisher_status() if s["publisher"] == "bus")

        # (both kinds: the queued one's thread may come round after ten inline ones)
        assert wait_for(lambda: d.bus.faults.total >= 10 and "TypeError" in bus()["error_kinds"])
        st = bus()
        assert d.sessions[0].faults.total == 0  # the board's reading went on, untouched
    kinds = st["error_kinds"]
    assert "ValueError in callback on /thesis/quad x" in kinds
    assert "TypeError in callback on /thesis/* x" in kinds
    assert st["errors"] == st["callback_errors"] and st["level"] == 1
    assert len(tracebacks(caplog, "ValueError in callback on /thesis/quad")) == 1
    assert len(tracebacks(caplog, "TypeError in callback on /thesis/*")) == 1


# ---- the daemon's own faces: the fan-out, the control endpoint ---------------------------------
class FailingFace(Publisher):
    """A face of an application's that cannot carry anything (its status is its own)."""

    name = "failing"

    def add_topic(self, topic: Any) -> None:
        raise NotImplementedError("no topics here")

    def publish(self, update: Update) -> None:
        raise OSError("gone")

    def diagnostics(self, status: list[dict[str, Any]], now_ns: int) -> None:
        raise RuntimeError("no diagnostics either")

    def status(self) -> dict[str, Any]:
        return {"publisher": self.name, "level": 0, "message": "fine, it says"}


def test_a_face_that_raises_is_counted_in_its_status_and_the_others_go_on(serve: Any) -> None:
    server = serve(make_sim("thesis", seed=3, name="thesis"))
    cfg = Config(boards=[BoardSpec(server.url)], diagnostics_period=0.1)
    face = FailingFace()
    with Daemon(cfg, extra_publishers=[face]) as d:
        assert d.wait_until_up(10)
        got: list[Update] = []
        d.subscribe("/thesis/quad", got.append)
        assert wait_for(lambda: len(got) > 3)  # the bus carries on
        assert wait_for(lambda: face.faults.total > 10)
        assert wait_for(lambda: "RuntimeError in diagnostics" in face.faults.summary(9))
        st = next(s for s in d.publisher_status() if s["publisher"] == "failing")
    kinds = {k.kind for k in face.faults.kinds()}
    assert {"NotImplementedError in add_topic", "OSError in publish"} <= kinds
    assert "RuntimeError in diagnostics" in kinds
    assert st["errors"] > 10 and "OSError in publish" in st["error_kinds"]


def test_a_control_handler_that_raises_is_counted_and_answered(tmp_path: Path) -> None:
    path = str(tmp_path / "control.sock")

    def broken(r: dict[str, Any]) -> dict[str, Any]:
        raise ZeroDivisionError("a bug of ours")

    server = ControlServer(path, {"boom": broken})
    try:
        answers = [ask(path, {"op": "boom"}, 5.0) for _ in range(3)]
    finally:
        server.close()
    assert all(a["error"].startswith("internal error: ZeroDivisionError") for a in answers)
    st = server.status()
    assert st["errors"] == 3 and st["error_kinds"].startswith("ZeroDivisionError in op boom x3")
