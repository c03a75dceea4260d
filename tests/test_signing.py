"""Signed J2A records for boards on a network link (board/signing.py, transport/signed.py;
docs/signing.md): the golden bytes, forgeries, replays and unsigned bytes dropped and counted,
and the MicroPython firmware under the real MicroPython on a signed link with an attacker
between it and the host that injects, replays and alters records."""

from __future__ import annotations

import hashlib
import hmac
import random
import socket
import struct
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from missing_link.board.signing import (
    BOARD_LINK,
    HOST_LINK,
    Signer,
    Verifier,
    board_now,
    hmac_sha256,
    host_now,
)
from missing_link.errors import BadURL, MissingLinkError
from missing_link.host.board import Board
from missing_link.j2a import SOF, encode_frame
from missing_link.transport import check_url, open_transport

from .helpers import FirmwareSim, free_port, wait_for

ROOT = Path(__file__).resolve().parent.parent
WIFI = ROOT / "examples" / "boards" / "esp32-wifi.py"
KEY = bytes(range(32))

# docs/signing.md's examples
ECHO_REQUEST = bytes.fromhex("120103006e")  # a2jEcho (opcode 3), seq 1, no payload
ECHO_RECORD = bytes.fromhex("4a324153009a78563412000500120103006eb31f06f208e7a03e")
ECHO_REPLY = encode_frame(SOF, 1, 0xBA, b"")
ECHO_REPLY_RECORD = bytes.fromhex("4a32415301dc050000010005001201ba00a581362fb5f2742e3a")


def test_golden_records() -> None:
    assert encode_frame(SOF, 1, 3, b"") == ECHO_REQUEST
    assert Signer(KEY, HOST_LINK).seal(ECHO_REQUEST, 0x0000123456789A) == ECHO_RECORD
    assert Signer(KEY, BOARD_LINK).seal(ECHO_REPLY, board_now(1, 1500)) == ECHO_REPLY_RECORD
    assert Verifier(KEY, HOST_LINK).feed(ECHO_RECORD) == ECHO_REQUEST
    assert host_now(1_420_070_400_000_000_000 + 10_000) == 1  # 10 µs units since 2015


def test_hmac_is_the_standard_one() -> None:
    rng = random.Random(1)
    for n in (0, 1, 55, 56, 64, 65, 300):
        data, key = rng.randbytes(n), rng.randbytes(rng.choice((16, 32, 70)))
        assert hmac_sha256(key, data) == hmac.new(key, data, hashlib.sha256).digest()


def test_forgeries_replays_and_unsigned_bytes_are_dropped_and_counted() -> None:
    rng = random.Random(7)
    signer = Signer(KEY, HOST_LINK)
    records = [signer.seal(rng.randbytes(rng.randrange(1, 60)), 100 + k) for k in range(20)]
    v = Verifier(KEY, HOST_LINK)
    # byte by byte, with unsigned bytes in between: every record comes through
    stream = b"".join(b"\x12junk" + r for r in records)
    out = b"".join(v.feed(stream[i : i + 1]) for i in range(len(stream)))
    assert out == b"".join(r[13:-8] for r in records) and v.records == 20
    assert v.junk == 20 * 5
    # a replay, one altered bit, a record signed with another key, one for the other direction
    flipped = bytearray(records[3])
    flipped[rng.randrange(len(flipped))] ^= 1 << rng.randrange(8)
    other = Signer(bytes(32), HOST_LINK).seal(b"x", 999)
    reflected = Signer(KEY, BOARD_LINK).seal(b"x", 999)
    assert v.feed(records[5] + bytes(flipped) + other + reflected) == b""
    assert v.replayed >= 1 and v.bad_tags + v.replayed >= 3 and v.records == 20
    # the stream goes on after all that
    assert v.feed(signer.seal(b"next", 10_000)) == b"next"


def test_timestamps_only_grow() -> None:
    s = Signer(KEY, BOARD_LINK)
    stamps = [struct.unpack("<Q", s.seal(b"", 50)[5:11] + b"\0\0")[0] for _ in range(3)]
    assert stamps == [50, 51, 52]  # a clock that stands still: one more each time
    assert board_now(2, 0) > board_now(1, 0xFFFFFFFF)  # a restarted board stamps newer


def test_urls_and_keys(tmp_path: Path) -> None:
    with pytest.raises(BadURL, match="needs \\?key=FILE"):
        check_url("signed+tcp://127.0.0.1:5000")
    with pytest.raises(BadURL, match=r"signing key .*: 32 bytes"):
        (tmp_path / "bad.key").write_text("short")
        check_url(f"signed+tcp://127.0.0.1:5000?key={tmp_path}/bad.key")
    (tmp_path / "k").write_text(KEY.hex() + "\n")
    assert check_url(f"signed+tcp://127.0.0.1:5000?key={tmp_path}/k") == "tcp"


# ---- the MicroPython firmware on a signed link, an attacker in between -------------------------
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


@pytest.fixture
def wifi(tmp_path: Path) -> Iterator[tuple[FirmwareSim, Path]]:
    key = tmp_path / "robot.key"  # (a key of its own: the host remembers a key's newest stamp)
    key.write_text(random.randbytes(32).hex() + "\n")
    sim = FirmwareSim(WIFI, files={"mlkey.bin": key})
    try:
        yield sim, key
    finally:
        sim.close()


def link_stats(board: Board) -> tuple[int, int, int, int]:
    return struct.unpack("<IIII", board.call_ok("a2jLinkStats"))  # type: ignore[return-value]


def test_a_signed_board_takes_nothing_unsigned(wifi: tuple[FirmwareSim, Path]) -> None:
    sim, key = wifi
    with pytest.raises(MissingLinkError):  # plain J2A: no answer at all
        Board(open_transport(sim.url), timeout=1.0).handshake()
    board = Board(open_transport(f"signed+{sim.url}?key={key}"), timeout=5.0)
    try:
        board.handshake()  # a new connection: the old one's bytes are gone with it
        assert board.properties["board.name"] == "wifi"
        records, bad, replayed, _junk = link_stats(board)
        assert records > 0 and bad == replayed == 0
    finally:
        board.close()


def test_an_attacker_between_host_and_board(wifi: tuple[FirmwareSim, Path]) -> None:
    sim, key = wifi
    relay = Relay(("127.0.0.1", int(sim.url.rsplit(":", 1)[1])))
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
        stats = board.transport.link_stats()  # type: ignore[attr-defined]
        assert stats["signed_bad_tags"] >= 1
        assert board.call("a2jEcho").code == 0xBA  # and the link goes on
        assert after[0] < link_stats(board)[0]
    finally:
        board.close()


def test_the_firmwares_tcp_link_with_a_signed_host(tmp_path: Path) -> None:
    """board/link.py's TcpLink and SignedLink (what an ESP32 runs) around a board runtime, on
    CPython: a host with the key gets its answers, the boot count moves the board's stamps."""
    from missing_link.board.link import TcpLink, signed
    from missing_link.virtual import make_sim

    key = tmp_path / "k"
    key.write_text(KEY.hex())
    port = free_port()
    cfg = {"kind": "tcp", "key_file": str(key), "boot_file": str(tmp_path / "boots"),
           "replay_file": str(tmp_path / "replay")}  # fmt: skip
    rt = make_sim("thesis", 1)
    link = signed(TcpLink(port, "127.0.0.1"), cfg, lambda: rt.clock() // 1000)
    stop = threading.Event()

    def serve() -> None:
        while not stop.is_set():
            data = link.read()
            if data:
                rt.feed(data, rt.clock())
            rt.poll()
            out = rt.take_output()
            if out:
                link.write(out)
            link.wait(2000)
        link.close()

    t = threading.Thread(target=serve, daemon=True)
    t.start()
    try:
        with Board.open(f"signed+tcp://127.0.0.1:{port}?key={key}", timeout=5.0) as board:
            assert board.properties["board.name"] == "thesis"
            assert board.call("a2jEcho", b"hi").payload == b"hi"
    finally:
        stop.set()
        t.join(5)
    assert (tmp_path / "boots").read_text() == "1"


def test_keys_are_made_and_put_on_boards_over_usb_only(tmp_path: Path) -> None:
    import os
    import stat
    import subprocess
    import sys

    ml = [sys.executable, "-m", "missing_link"]
    key = tmp_path / "robot.key"
    r = subprocess.run([*ml, "key", "new", str(key)], capture_output=True, text=True, timeout=30)
    assert r.returncode == 0 and len(bytes.fromhex(key.read_text().strip())) == 32
    assert stat.S_IMODE(os.stat(key).st_mode) == 0o600
    r = subprocess.run([*ml, "key", "new", str(key)], capture_output=True, text=True, timeout=30)
    assert r.returncode == 2 and "exists" in r.stderr
    flash = [*ml, "flash", str(WIFI), "--dry-run"]
    r = subprocess.run(flash, capture_output=True, text=True, timeout=30)
    assert r.returncode != 0 and "give the key with --key" in r.stderr
    r = subprocess.run([*flash, "--key", str(key)], capture_output=True, text=True, timeout=30)
    assert r.returncode == 0 and f"{key} -> :mlkey.bin" in r.stdout, r.stderr
    r = subprocess.run(
        [*flash, "--key", str(key), "--port", "tcp://10.0.0.5:5000"],
        capture_output=True, text=True, timeout=30,
    )  # fmt: skip
    assert r.returncode != 0 and "over USB only" in r.stderr and r.stderr.count("\n") == 1
