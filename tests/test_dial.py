"""Boards that dial in (issue 36.3, docs/hardware.md "Boards that dial in", docs/signing.md):
the board's side (board/dial.py: backoff on virtual time; link.py's SocketNet on real sockets),
the daemon's listener and its routing by board.id (daemon/intake/listener.py, dialin.py), and
MicroPython boards under the real MicroPython (node) dialing a real daemon over loopback TCP,
one killed and restarted; signed dial-ins; virtual boards (``board --sim --dial``)."""

from __future__ import annotations

import dataclasses
import os
import socket
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from missing_link.board.dial import DialServer, dial_address
from missing_link.board.link import SocketNet
from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, parse_config
from missing_link.daemon.intake.dialin import DialIns
from missing_link.daemon.listen_spec import parse_listen
from missing_link.daemon.session.link import Mailbox
from missing_link.daemon.session.status import SessionState
from missing_link.deploy.boardfile import check_board, load_board_file
from missing_link.errors import BadURL, CallTimeout, ConfigError
from missing_link.host.link import CallResult

from .helpers import FirmwareSim, wait_for

ROOT = Path(__file__).resolve().parent.parent


# ---- the board's side: dialing, backoff (pure, virtual time) ----------------------------------
class FakeNet:
    """Connections that come up, fail or end when the test says."""

    def __init__(self) -> None:
        self.dialed: list[tuple[str, int]] = []
        self.state: dict[int, bool | None] = {}
        self.dropped: list[int] = []

    def connect(self, host: str, port: int) -> int:
        self.dialed.append((host, port))
        n = len(self.dialed)
        self.state[n] = False
        return n

    def connected(self, n: int) -> bool | None:
        return self.state.get(n)

    def recv(self, n: int) -> bytes | None:
        return b"" if self.state.get(n) is None else None

    def send(self, n: int, data: bytes) -> bool:
        return bool(self.state.get(n))

    def drop(self, n: int) -> None:
        self.dropped.append(n)

    def wait(self, us: int) -> None:
        pass

    def close(self) -> None:
        pass


def test_a_board_dials_again_with_a_backoff_that_doubles_and_resets() -> None:
    now = [0]
    net = FakeNet()
    d = DialServer(net, "10.0.0.2", 7000, lambda: now[0])
    gaps: list[int] = []
    for _ in range(7):  # refused, again and again: 250, 500, ... ms, at most 8 s
        start = now[0]
        while d.accept() is None and len(net.dialed) == len(gaps):
            now[0] += 10
        gaps.append(now[0] - start)
        net.state[len(net.dialed)] = None  # refused
        assert d.accept() is None
    assert gaps[1:] == [250, 500, 1000, 2000, 4000, 8000]
    assert net.dialed[0] == ("10.0.0.2", 7000)
    while len(net.dialed) == 7:  # the 8th dial succeeds, and lasts
        now[0] += 10
        d.accept()
    net.state[8] = True
    assert d.accept() == 8 and d.connects == 1
    now[0] += DialServer.STEADY_MS
    net.state[8] = None  # the host closed it
    assert d.recv(8) == b""
    start = now[0]
    while len(net.dialed) == 8:
        now[0] += 10
        d.accept()
    assert now[0] - start == 250  # back at the minimum after a steady connection
    while d.accept() is None:  # never comes up: given up after CONNECT_MS, dialed again
        now[0] += 100
        if len(net.dialed) > 9:
            break
    assert 9 in net.dropped and len(net.dialed) == 10


@pytest.mark.parametrize(
    ("text", "ok"),
    [("192.168.1.10:7000", True), ("127.0.0.1:1", True), ("host", False), (":7000", False),
     ("1.2.3.4:0", False), ("1.2.3.4:99999", False), ("1.2.3.4:x", False)],
)  # fmt: skip
def test_dial_addresses(text: str, ok: bool) -> None:
    if ok:
        host, port = dial_address(text)
        assert f"{host}:{port}" == text
    else:
        with pytest.raises(ValueError, match="link dial must be 'HOST:PORT'"):
            dial_address(text)


def test_socket_net_connects_without_blocking_and_says_when_it_was_refused() -> None:
    """link.py's SocketNet (the device's) on CPython's sockets: up, and refused."""
    srv = socket.create_server(("127.0.0.1", 0))
    port = srv.getsockname()[1]
    gone = socket.create_server(("127.0.0.1", 0))
    closed_port = gone.getsockname()[1]
    gone.close()
    net = SocketNet()
    try:
        up, refused = net.connect("127.0.0.1", port), net.connect("127.0.0.1", closed_port)
        assert wait_for(lambda: net.connected(up) is True, 5)
        assert wait_for(lambda: net.connected(refused) is None, 5)
        peer, _ = srv.accept()
        assert net.send(up, b"hello") and peer.recv(5) == b"hello"
        peer.sendall(b"back")
        assert wait_for(lambda: net.recv(up) == b"back", 5)
        peer.close()
        assert wait_for(lambda: net.recv(up) == b"", 5)  # (closed by the host: forgotten)
        assert net.connected(up) is None
    finally:
        net.close()
        srv.close()


@pytest.mark.parametrize(
    ("link", "message"),
    [
        ({"kind": "tcp", "dial": "robot-pc:7000"}, "the daemon's IPv4 address and port"),
        ({"kind": "tcp", "dial": "10.0.0.1:0"}, "the daemon's IPv4 address and port"),
        ({"kind": "tcp", "dial": "10.0.0.1:7000", "port": 5000}, "a board that dials has no port"),
        ({"kind": "uart", "dial": "10.0.0.1:7000"}, "not a key of a uart link"),
    ],
)
def test_board_files_name_where_the_board_dials(link: dict[str, Any], message: str) -> None:
    board = {"name": "wifi", "mcu": "esp32", "link": link,
             "transducers": [{"name": "servo", "id": 1, "driver": "servo", "pin": 13}]}  # fmt: skip
    with pytest.raises(ConfigError, match=message):
        check_board(board, "wifi.py")
    board["link"] = {"kind": "tcp", "dial": "10.0.0.1:7000", "key_file": "mlkey.bin"}
    check_board(board, "wifi.py")
    example = load_board_file(ROOT / "examples" / "boards" / "esp32-dial.py")
    assert example.board["link"]["dial"] == "192.168.1.10:7000"


@pytest.mark.slow
# ---- the daemon's side: where it listens, and which session a board goes to ------------------
def test_listening_off_loopback_needs_signing(tmp_path: Path) -> None:
    assert parse_listen("tcp://127.0.0.1:7000").loopback
    with pytest.raises(BadURL, match="off loopback must sign: listen on signed"):
        parse_listen("tcp://0.0.0.0:7000")
    with pytest.raises(BadURL, match="signed\\+ needs \\?key=FILE"):
        parse_listen("signed+tcp://0.0.0.0:7000")
    with pytest.raises(BadURL, match="signing key"):
        parse_listen(f"signed+tcp://0.0.0.0:7000?key={tmp_path / 'none.key'}")
    key = tmp_path / "k.key"
    key.write_text("ab" * 32)
    assert parse_listen(f"signed+tcp://0.0.0.0:7000?key={key}").key_file == str(key)
    with pytest.raises(ConfigError, match=r"daemon\.accept"):
        parse_config({"daemon": {"accept": "some"}})
    with pytest.raises(ConfigError, match=r"daemon\.listen: 'udp://x'"):
        parse_config({"daemon": {"listen": "udp://x"}})
    r = subprocess.run(
        [sys.executable, "-m", "missing_link", "run", "--listen", "tcp://0.0.0.0:7000"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert "off loopback must sign" in r.stderr


class FakeBoard:
    def __init__(self, epoch: str, board_id: str = "b1") -> None:
        self.properties = {"board.id": board_id, "clock.epoch": epoch}
        self.alive = True
        self.answers = True  # (to the probe of an old link: dialin.answers)

    def close(self) -> None:
        self.alive = False

    def call(self, name: str, payload: bytes, timeout: float) -> CallResult:
        if not (self.alive and self.answers and name == "a2jEcho"):
            raise CallTimeout("fake", name, "no answer")
        return CallResult(0xBA, payload)


class FakeSession:
    """What dialin.py reads of a session: its board, state, epoch and spec; ``connect`` takes
    the board handed over, as the session's thread does."""

    def __init__(self, spec: BoardSpec, box: Mailbox) -> None:
        self.spec = dataclasses.replace(spec, link_timeout=0.05)
        self.box = box
        self.board: Any = None
        self.state = "connecting"
        self.epoch = ""

    def connect(self) -> None:
        self.board = self.box.take(threading.Event())
        self.state, self.epoch = "up", self.board.properties["clock.epoch"]


@pytest.fixture
def dialins() -> Iterator[tuple[DialIns, list[FakeSession]]]:
    made: list[FakeSession] = []

    def add(spec: BoardSpec, box: Mailbox) -> Any:
        made.append(FakeSession(spec, box))
        return made[-1]

    cfg = parse_config({"boards": {"left": {"id": "b1"}}})
    d = DialIns(cfg, parse_listen("tcp://127.0.0.1:0"), add)
    yield d, made
    d.stop()


def test_a_board_goes_to_the_session_of_its_id(dialins: tuple[DialIns, list[FakeSession]]) -> None:
    d, made = dialins
    first = FakeBoard("e1")
    assert d.hand_over(first) is None  # type: ignore[arg-type]
    (s,) = made
    assert s.spec.name == "left" and s.spec.url == "dial://b1"  # (named by the config's id)
    s.connect()
    # the same boot dials again (its old connection is dead): the old link is closed at once
    first.answers = False
    again = FakeBoard("e1")
    assert d.hand_over(again) is None  # type: ignore[arg-type]
    assert not first.alive and len(made) == 1
    s.connect()
    # the board restarted and its link has gone: the same session takes it
    s.board.close()
    back = FakeBoard("e2")
    assert d.hand_over(back) is None  # type: ignore[arg-type]
    s.connect()
    assert s.board is back and len(made) == 1
    # another board states the same id while this one is up (after a link_timeout): its own
    twin = FakeBoard("e3")
    assert d.hand_over(twin) is None  # type: ignore[arg-type]
    assert len(made) == 2 and made[1].box.waiting is twin and back.alive
    # no id, or (accept = "known") an id the config does not name: refused, saying why
    assert "states no board.id" in str(d.hand_over(FakeBoard("e4", board_id="")))  # type: ignore[arg-type]
    odd = d.hand_over(FakeBoard("e4", board_id="a\x1b[2Jb"))  # type: ignore[arg-type]
    assert odd is not None and "not 1..64 printable ASCII" in odd and len(made) == 2
    d.config.accept = "known"
    why = d.hand_over(FakeBoard("e5", board_id="b9"))  # type: ignore[arg-type]
    assert why is not None and '[boards.NAME] id = "b9"' in why and len(made) == 2


# ---- MicroPython boards dialing a real daemon ---------------------------------------------------
DIALING = """BOARD = {{
    "name": "wifi",
    "mcu": "esp32",
    "link": {{"kind": "tcp", "dial": "127.0.0.1:{port}"{key}}},
    "transducers": [
        {{"name": "dist_ir", "id": 0, "driver": "sharp_gp2y0a02", "pin": 34, "rate_hz": 20}},
        {{"name": "servo", "id": 1, "driver": "servo", "pin": 13, "call": "a2j_set_servo"}},
    ],
}}
"""


def chip_id(seed: int) -> str:
    import hashlib

    return hashlib.sha256(b"missing-link sim board %d" % seed).digest()[:8].hex()


def dialing_board(tmp_path: Path, port: int, key: bool = False) -> Path:
    p = tmp_path / f"dial-{port}-{key}.py"
    p.write_text(DIALING.format(port=port, key=', "key_file": "mlkey.bin"' if key else ""))
    return p


def listening(listen: str, doc: dict[str, Any] | None = None) -> Daemon:
    cfg = parse_config(doc or {})
    cfg.listen = listen
    return Daemon(cfg)


def samples(d: Daemon, name: str) -> int:
    return next((s["samples"] for s in d.status() if s["board"] == name), 0)


@pytest.mark.slow
@pytest.mark.micropython
def test_micropython_boards_dial_in_and_one_comes_back_as_itself(tmp_path: Path) -> None:
    """Two boards (their own chip ids) dial a daemon on loopback; the config names them by id
    and sets a key of each.  One is killed and restarted: it dials again and comes back under
    the same name, topics and configuration, in the same session; the other never stops."""
    doc = {"boards": {"left": {"id": chip_id(1), "config": {"dist_ir.rate_hz": 5}},
                      "right": {"id": chip_id(2), "config": {"dist_ir.rate_hz": 10}}}}  # fmt: skip
    with listening("tcp://127.0.0.1:0", doc) as d:
        assert d.dialins is not None
        board_file = dialing_board(tmp_path, d.dialins.listener.port)
        sims = {k: FirmwareSim(board_file, args=["--seed", str(k)]) for k in (1, 2)}
        try:
            assert wait_for(lambda: len(d.sessions) == 2 and d.wait_until_up(0.1), 20), d.status()
            st = {s["board"]: s for s in d.status()}
            assert set(st) == {"left", "right"}
            assert (
                st["left"]["board_id"] == chip_id(1) and st["left"]["url"] == f"dial://{chip_id(1)}"
            )
            assert st["left"]["address"].startswith("tcp://127.0.0.1:")
            assert d.board_config("left")["dist_ir.rate_hz"] == 5.0
            assert wait_for(lambda: samples(d, "left") > 3 and samples(d, "right") > 3, 10)
            topics = set(d.bus.topics)
            assert {"/left/dist_ir", "/right/dist_ir", "/left/servo"} <= topics
            sims[1].close()  # killed
            left = d.session("left")
            assert wait_for(lambda: left.state != SessionState.UP, 10)
            right_before = samples(d, "right")
            sims[1] = FirmwareSim(board_file, args=["--seed", "1"])  # restarted: dials again
            assert wait_for(lambda: left.state == SessionState.UP and left.connects == 2, 20), (
                d.status()
            )
            assert [s.name for s in d.sessions] == ["left", "right"]  # the same two sessions
            assert set(d.bus.topics) == topics
            assert d.board_config("left")["dist_ir.rate_hz"] == 5.0  # applied again
            assert samples(d, "right") > right_before and d.session("right").connects == 1
            before = samples(d, "left")
            assert wait_for(lambda: samples(d, "left") > before, 10)
            listener = d.dialins.status()
            assert listener["accepted"] == listener["handed"] == 3 and listener["refused"] == 0
        finally:
            for sim in sims.values():
                sim.close()


@pytest.mark.slow
@pytest.mark.micropython
def test_a_board_dials_again_when_its_daemon_comes_back(tmp_path: Path) -> None:
    """The daemon stops (the board hears goodbye, its connection ends) and another starts on
    the same port a while later: the board, dialing with backoff meanwhile, comes up there."""
    first = listening("tcp://127.0.0.1:0").start()
    assert first.dialins is not None
    port = first.dialins.listener.port
    sim = FirmwareSim(dialing_board(tmp_path, port), args=["--seed", "5"])
    try:
        assert wait_for(lambda: first.sessions and first.wait_until_up(0.1), 20), first.status()
        first.stop()
        assert wait_for(lambda: sim.ctl("result = fw.link.server.dials") >= 3, 20)
        with listening(f"tcp://127.0.0.1:{port}") as again:
            assert wait_for(lambda: again.sessions and again.wait_until_up(0.1), 30)
            assert again.status()[0]["board_id"] == chip_id(5)
            dials, connects = sim.ctl("result = (fw.link.server.dials, fw.link.server.connects)")
            assert connects == 2 and dials > connects  # (refused meanwhile, dialed again)
    finally:
        first.stop()
        sim.close()


@pytest.mark.slow
@pytest.mark.micropython
def test_known_boards_only_and_two_boards_with_one_id(tmp_path: Path) -> None:
    """``accept = "known"``: a board whose id the config does not name is refused (and dials
    again later); two boards with one chip id are both shown, with the warning."""
    doc = {"daemon": {"accept": "known"}, "boards": {"left": {"id": chip_id(1)}}}
    with listening("tcp://127.0.0.1:0", doc) as d:
        assert d.dialins is not None
        board_file = dialing_board(tmp_path, d.dialins.listener.port)
        sims = [FirmwareSim(board_file, args=["--seed", str(k)]) for k in (1, 3, 1)]
        try:
            assert wait_for(lambda: len(d.sessions) == 2 and d.wait_until_up(0.1), 20), d.status()
            st = d.status()
            assert sorted(s["board"] for s in st) == ["left", "left_2"]
            assert all("is stated by another connected board too" in s["warnings"] for s in st)
            assert all(s["board_id"] == chip_id(1) for s in st)
            listener = d.dialins.status()
            assert listener["refused"] >= 1 and "refused x" in listener["refused_kinds"]
        finally:
            for sim in sims:
                sim.close()


@pytest.mark.slow
@pytest.mark.micropython
def test_a_signed_board_dials_in_and_another_key_is_refused(tmp_path: Path) -> None:
    """The daemon greets the board that connected (HELLO out, its CHALLENGE checked), as it
    greets a board it connects to: the roles of who connects change, not who proves the key."""
    keys = [tmp_path / "robot.key", tmp_path / "other.key"]
    for k in keys:
        k.write_text(os.urandom(32).hex() + "\n")
    with listening(f"signed+tcp://127.0.0.1:0?key={keys[0]}") as d:
        assert d.dialins is not None and d.dialins.listener.url.startswith("signed+tcp://")
        board_file = dialing_board(tmp_path, d.dialins.listener.port, key=True)
        good = FirmwareSim(board_file, files={"mlkey.bin": keys[0]}, args=["--seed", "1"])
        bad = FirmwareSim(board_file, files={"mlkey.bin": keys[1]}, args=["--seed", "2"])
        try:
            assert wait_for(lambda: d.sessions and d.wait_until_up(0.1), 20), d.status()
            assert wait_for(lambda: "greeting failed" in d.dialins.status()["refused_kinds"], 20)
            (s,) = d.status()
            assert s["board_id"] == chip_id(1) and s["address"].startswith("signed+tcp://")
            assert s["signed_records"] > 0 and s["signed_bad_tags"] == 0
            assert wait_for(lambda: samples(d, "wifi") > 3, 10)
        finally:
            good.close()
            bad.close()
