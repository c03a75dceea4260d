"""Signed boards on a real network link (docs/signing.md): the MicroPython firmware under the
real MicroPython (node) and the firmware's own TCP server (board/link.py, on CPython) with the
host's ``signed+`` transport; an attacker in between that injects, replays and alters records;
clients without the key that connect over and over beside a daemon; a host whose wall clock
jumps; and mismatches said by name."""

from __future__ import annotations

import random
import socket
import struct
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from missing_link.board.signing import hello
from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config
from missing_link.daemon.session.status import SessionState
from missing_link.errors import MissingLinkError, TransportBroken
from missing_link.host.board import Board
from missing_link.j2a import SOF, encode_frame
from missing_link.transport import open_transport

from .helpers import FirmwareSim, free_port, wait_for

ROOT = Path(__file__).resolve().parent.parent
WIFI = ROOT / "examples" / "boards" / "esp32-wifi.py"
TEN_YEARS_NS = 10 * 365 * 86400 * 10**9


def new_key(path: Path) -> Path:
    path.write_text(random.randbytes(32).hex() + "\n")
    return path


class Relay:
    """A TCP man in the middle: hands bytes on, through ``to_board``/``to_host`` hooks."""

    def __init__(self, target: tuple[str, int]) -> None:
        self.srv = socket.create_server(("127.0.0.1", 0))
        self.port = self.srv.getsockname()[1]
        self.target = target
        self.to_board: Callable[[bytes], bytes] = lambda b: b
        self.to_host: Callable[[bytes], bytes] = lambda b: b
        self.board_sock: socket.socket | None = None
        self.host_sock: socket.socket | None = None
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self) -> None:
        host, _ = self.srv.accept()
        board = socket.create_connection(self.target)
        self.host_sock, self.board_sock = host, board
        threading.Thread(target=self._pump, args=(board, host, "to_host"), daemon=True).start()
        self._pump(host, board, "to_board")

    def _pump(self, src: socket.socket, dst: socket.socket, hook: str) -> None:
        try:
            while data := src.recv(4096):
                dst.sendall(getattr(self, hook)(data))
        except OSError:
            pass
        for s in (src, dst):
            s.close()


class Flood:
    """Clients without the key, one connection every ``every_s``, each doing one of the
    things a client can do: nothing, junk, plain J2A, a hello with another key (and then
    waiting), closing at once."""

    def __init__(self, port: int, every_s: float = 0.05) -> None:
        self.port, self.every_s = port, every_s
        self.connects = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        rng = random.Random(5)
        held: list[socket.socket] = []
        while not self._stop.wait(self.every_s):
            try:
                s = socket.create_connection(("127.0.0.1", self.port), timeout=1)
            except OSError:
                continue
            self.connects += 1
            what = self.connects % 5
            try:
                if what == 1:
                    s.sendall(rng.randbytes(64))
                elif what == 2:
                    s.sendall(encode_frame(SOF, 1, 0, b""))
                elif what == 3:
                    s.sendall(hello(bytes(32), rng.randbytes(16)))
            except OSError:
                pass
            if what == 4:
                s.close()
            else:
                held.append(s)  # (left open: the board closes them)
            while len(held) > 8:
                held.pop(0).close()
        for s in held:
            s.close()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)


@pytest.fixture
def wifi(tmp_path: Path) -> Iterator[tuple[FirmwareSim, Path]]:
    key = new_key(tmp_path / "robot.key")
    sim = FirmwareSim(WIFI, files={"mlkey.bin": key})
    try:
        yield sim, key
    finally:
        sim.close()


def link_stats(board: Board) -> tuple[int, int, int, int]:
    return struct.unpack("<IIII", board.call_ok("a2jLinkStats"))  # type: ignore[return-value]


def sim_port(sim: FirmwareSim) -> int:
    return int(sim.url.rsplit(":", 1)[1])


# ---- the MicroPython firmware -------------------------------------------------------------------
@pytest.mark.slow
def test_a_signed_board_takes_nothing_unsigned(wifi: tuple[FirmwareSim, Path]) -> None:
    sim, key = wifi
    with pytest.raises(MissingLinkError):  # plain J2A: the connection is closed, no answer
        Board(open_transport(sim.url), timeout=1.0).handshake()
    board = Board(open_transport(f"signed+{sim.url}?key={key}"), timeout=5.0)
    try:
        board.handshake()
        assert board.properties["board.name"] == "wifi"
        records, bad, replayed, _junk = link_stats(board)
        assert records > 0 and bad == replayed == 0
    finally:
        board.close()


@pytest.mark.slow
def test_an_attacker_between_host_and_board(wifi: tuple[FirmwareSim, Path]) -> None:
    sim, key = wifi
    relay = Relay(("127.0.0.1", sim_port(sim)))
    board = Board(open_transport(f"signed+tcp://127.0.0.1:{relay.port}?key={key}"), timeout=5.0)
    try:
        board.handshake()
        seen: list[bytes] = []
        relay.to_board = lambda b: (seen.append(b), b)[1]
        board.call_ok("a2j_set_servo", b"\x28")  # 40: recorded on its way
        servo = "result = WORLD.pulse_us(13)"
        assert wait_for(lambda: sim.ctl(servo) > 1500)
        moved = [r for r in seen if len(r) > 13]
        board.call_ok("a2j_set_servo", b"\xd8")  # -40
        assert wait_for(lambda: sim.ctl(servo) < 1500)
        assert relay.board_sock is not None
        before = link_stats(board)
        # 1. a replay of the command to 40: refused, the servo stays at -40
        relay.board_sock.sendall(moved[-1])
        # 2. an unsigned J2A frame commanding 127
        relay.board_sock.sendall(encode_frame(SOF, 9, board.index["a2j_set_servo"], b"\x7f"))
        # 3. an altered record: the next real one has a bit flipped on the way
        relay.to_board = lambda b: bytes((b[0] ^ 1,)) + b[1:] if len(b) > 20 else b
        with pytest.raises(MissingLinkError):
            board.call("a2j_set_servo", b"\x7f", timeout=1.0)
        relay.to_board = lambda b: b
        _records, bad, replayed, junk = after = link_stats(board)
        assert sim.ctl(servo) < 1500  # none of it moved the servo
        assert replayed > before[2] and junk > before[3] and bad + junk > before[1] + before[3]
        # the board's replies: an altered one and a replayed one are dropped by the host
        relay.to_host = lambda b: b[:-1] + bytes((b[-1] ^ 0x80,))
        with pytest.raises(MissingLinkError):
            board.call("a2jEcho", timeout=1.0)
        relay.to_host = lambda b: b
        stats = board.link.transport.link_stats()  # type: ignore[attr-defined]
        assert stats["signed_bad_tags"] >= 1
        assert board.call("a2jEcho").code == 0xBA  # and the link goes on
        assert after[0] < link_stats(board)[0]
    finally:
        board.close()


@pytest.mark.slow
def test_a_flood_of_clients_without_the_key_beside_the_daemon(
    wifi: tuple[FirmwareSim, Path],
) -> None:
    """Connecting every 50 ms kept the daemon off 98 % of the time when any connection took
    the link over: now the daemon keeps it, and its samples keep coming."""
    sim, key = wifi
    cfg = Config(boards=[BoardSpec(f"signed+{sim.url}?key={key}")], publishers=["bus"])
    with Daemon(cfg) as d:
        assert d.wait_until_up(15)
        got: list[object] = []
        d.subscribe("/wifi/dist_ir", got.append, queue=0)
        flood = Flood(sim_port(sim))
        try:
            ups = []
            for _ in range(30):  # 3 s of it
                time.sleep(0.1)
                ups.append(d.sessions[0].state == SessionState.UP)
            before = len(got)
            assert wait_for(lambda: len(got) > before + 3)  # (dist_ir: 10 Hz)
        finally:
            flood.stop()
        st = d.status()[0]
    assert flood.connects >= 20 and all(ups), ups
    assert st["connects"] == 1 and st["failures"] == 0, st
    # the signed link's own counters are among the board's (status, /diagnostics)
    assert st["signed_records"] > 0 and st["signed_bad_tags"] == 0, st


@pytest.mark.slow
def test_the_hosts_wall_clock_does_not_matter(
    wifi: tuple[FirmwareSim, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    """A host clock ten years ahead, then back to now, then a board restart: the host
    connects every time (the board used to keep the newest host timestamp, in flash too)."""
    sim, key = wifi
    url = f"signed+{sim.url}?key={key}"
    real = time.time_ns
    for step in (TEN_YEARS_NS, 0, -86400 * 10**9, 0):
        monkeypatch.setattr(time, "time_ns", lambda step=step: real() + step)
        with Board.open(url, timeout=5.0) as board:
            assert board.call("a2jEcho", b"t").payload == b"t"
        if step == 0:
            sim.ctl("reboot()")


@pytest.mark.slow
def test_a_stale_replay_file_from_the_clock_days_locks_nobody_out(tmp_path: Path) -> None:
    """A board flashed before this version kept the newest host timestamp in mlreplay.txt; one
    from a host clock ten years ahead locked every host out, across restarts and flashes."""
    key = new_key(tmp_path / "robot.key")
    stale = tmp_path / "mlreplay.txt"
    stale.write_text(str(2**47))
    sim = FirmwareSim(WIFI, files={"mlkey.bin": key, "mlreplay.txt": stale})
    try:
        with Board.open(f"signed+{sim.url}?key={key}", timeout=5.0) as board:
            assert board.properties["board.name"] == "wifi"
    finally:
        sim.close()


@pytest.mark.slow
def test_mismatches_are_named(wifi: tuple[FirmwareSim, Path], tmp_path: Path, serve) -> None:  # type: ignore[no-untyped-def]
    sim, _key = wifi
    other = new_key(tmp_path / "other.key")
    with pytest.raises(TransportBroken, match="the board's key differs"):
        open_transport(f"signed+{sim.url}?key={other}")
    # a board without a key (a virtual board: it streams its samples at once)
    plain = serve("thesis", "tcp://127.0.0.1:0")
    with pytest.raises(TransportBroken, match="answers in plain J2A"):
        open_transport(f"signed+{plain.url}?key={other}")
    # something that says nothing at all
    with socket.create_server(("127.0.0.1", 0)) as silent:
        url = f"signed+tcp://127.0.0.1:{silent.getsockname()[1]}?key={other}"
        with pytest.raises(TransportBroken, match="no answer to the signed hello"):
            open_transport(url)


# ---- the firmware's own TCP server (what an ESP32 runs), on CPython ----------------------------
class TcpBoard:
    """board/link.py's TcpServer and network_link around a board runtime, in a thread."""

    def __init__(self, tmp_path: Path, key: Path) -> None:
        from missing_link.board.link import TcpServer, network_link
        from missing_link.virtual import make_sim

        self.port = free_port()
        cfg = {"kind": "tcp", "key_file": str(key)}
        self.rt = make_sim("thesis", 1)
        server = TcpServer(self.port, "127.0.0.1")
        self.link = network_link(server, cfg, lambda: self.rt.clock() // 1000)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        rt, link = self.rt, self.link
        while not self._stop.is_set():
            data = link.read()
            if data:
                rt.feed(data, rt.clock())
            rt.poll()
            out = rt.take_output()
            if out:
                link.write(out)
            link.wait(2000)
        link.close()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5)


@pytest.mark.slow  # (seconds of real time)
def test_the_firmwares_tcp_server_keeps_its_host(tmp_path: Path) -> None:
    key = new_key(tmp_path / "k")
    tb = TcpBoard(tmp_path, key)
    try:
        with Board.open(f"signed+tcp://127.0.0.1:{tb.port}?key={key}", timeout=5.0) as board:
            assert board.properties["board.name"] == "thesis"
            flood = Flood(tb.port)
            try:
                for k in range(40):
                    assert board.call("a2jEcho", b"%d" % k).payload == b"%d" % k
                    time.sleep(0.05)
            finally:
                flood.stop()
            assert flood.connects >= 20
            assert board.call("a2jEcho", b"after").payload == b"after"
        # the host comes back on a new connection: it proves the key and takes the link
        with Board.open(f"signed+tcp://127.0.0.1:{tb.port}?key={key}", timeout=5.0) as board:
            assert board.call("a2jEcho", b"again").payload == b"again"
        assert tb.link.stats()["unproven"] >= 20
    finally:
        tb.close()
