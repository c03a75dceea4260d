"""Signed J2A records for boards on a network link (board/signing.py, transport/signed.py;
docs/signing.md): the golden bytes, forgeries, replays and unsigned bytes dropped and counted,
and the MicroPython firmware under the real MicroPython on a signed link with an attacker
between it and the host that injects, replays and alters records."""

from __future__ import annotations

import hashlib
import hmac
import random
import struct
from pathlib import Path

import pytest

from missing_link.board import signing
from missing_link.board.signing import (
    BOARD_LINK,
    CHALLENGE,
    HOST_LINK,
    MAGIC,
    MAX_DATA,
    SignedLink,
    Signer,
    Verifier,
    challenge,
    hello,
    hmac_sha256,
    seal,
    session_key,
)
from missing_link.errors import BadURL
from missing_link.j2a import SOF, encode_frame
from missing_link.transport import check_url

from .helpers import ml

ROOT = Path(__file__).resolve().parent.parent
WIFI = ROOT / "examples" / "boards" / "esp32-wifi.py"
KEY = bytes(range(32))

# docs/signing.md's examples: the key 00..1f, the host's nonce a0..af, the board's b0..bf
NH, NB = bytes(range(0xA0, 0xB0)), bytes(range(0xB0, 0xC0))
HELLO_RECORD = bytes.fromhex(
    "4a324153020000000000001000a0a1a2a3a4a5a6a7a8a9aaabacadaeaf2b5c655630aaaa25"
)
CHALLENGE_RECORD = bytes.fromhex(
    "4a32415303000000000000" "2000" "a0a1a2a3a4a5a6a7a8a9aaabacadaeaf"
    "b0b1b2b3b4b5b6b7b8b9babbbcbdbebf" "e2345d527f4b2c31"
)  # fmt: skip
SESSION = bytes.fromhex("8a94724764a127466d50f56df4266e46eea358074d9bee8a6689f9ada6ab7108")
ECHO_REQUEST = bytes.fromhex("120103006e")  # a2jEcho (opcode 3), seq 1, no payload
ECHO_RECORD = bytes.fromhex("4a324153000100000000000500120103006e017785a8ceb5c22d")
ECHO_REPLY = encode_frame(SOF, 1, 0xBA, b"")  # (return code 0xBA, as the 2014 firmware's echo)
ECHO_REPLY_RECORD = bytes.fromhex("4a3241530101000000000005001201ba00a5fe711982448c4ded")


def test_golden_records() -> None:
    assert encode_frame(SOF, 1, 3, b"") == ECHO_REQUEST
    assert hello(KEY, NH) == HELLO_RECORD
    assert challenge(KEY, NH, NB) == CHALLENGE_RECORD
    assert session_key(KEY, NH, NB) == SESSION
    assert hmac.new(KEY, b"J2AK" + NH + NB, hashlib.sha256).digest() == SESSION
    assert Signer(SESSION, HOST_LINK).seal(ECHO_REQUEST) == ECHO_RECORD
    assert Signer(SESSION, BOARD_LINK).seal(ECHO_REPLY) == ECHO_REPLY_RECORD
    for rec, key in ((HELLO_RECORD, KEY), (CHALLENGE_RECORD, KEY), (ECHO_RECORD, SESSION)):
        assert rec[-8:] == hmac.new(key, rec[:-8], hashlib.sha256).digest()[:8]
    assert Verifier(SESSION, HOST_LINK).feed(ECHO_RECORD) == ECHO_REQUEST


def test_hmac_is_the_standard_one() -> None:
    rng = random.Random(1)
    for n in (0, 1, 55, 56, 64, 65, 300):
        data, key = rng.randbytes(n), rng.randbytes(rng.choice((16, 32, 70)))
        assert hmac_sha256(key, data) == hmac.new(key, data, hashlib.sha256).digest()


def test_forgeries_replays_and_unsigned_bytes_are_dropped_and_counted() -> None:
    rng = random.Random(7)
    signer = Signer(SESSION, HOST_LINK)
    records = [signer.seal(rng.randbytes(rng.randrange(1, 60))) for _ in range(20)]
    v = Verifier(SESSION, HOST_LINK)
    # byte by byte, with unsigned bytes in between: every record comes through
    stream = b"".join(b"\x12junk" + r for r in records)
    out = b"".join(v.feed(stream[i : i + 1]) for i in range(len(stream)))
    assert out == b"".join(r[13:-8] for r in records) and v.counts["records"] == 20
    assert v.counts["junk"] == 20 * 5
    # a replay, one altered bit, a record of another connection (another session key), one
    # signed with the long-term key itself, one for the other direction
    flipped = bytearray(records[3])
    flipped[rng.randrange(13, len(flipped))] ^= 1 << rng.randrange(8)
    other = Signer(session_key(KEY, NH, bytes(16)), HOST_LINK)
    other.counter = 100
    long_term = seal(KEY, HOST_LINK, 101, b"x")
    reflected = seal(SESSION, BOARD_LINK, 102, b"x")
    assert v.feed(records[5] + bytes(flipped) + other.seal(b"x") + long_term + reflected) == b""
    assert v.counts["replayed"] == 1 and v.counts["bad_tags"] == 4 and v.counts["records"] == 20
    # the stream goes on after all that
    assert v.feed(signer.seal(b"next")) == b"next"


def test_counters_count_per_connection() -> None:
    s = Signer(SESSION, BOARD_LINK)
    assert [int.from_bytes(s.seal(b"")[5:11], "little") for _ in range(3)] == [1, 2, 3]
    # a record of an earlier connection carries an earlier session: it never checks now
    old = Signer(session_key(KEY, NH, bytes(16)), HOST_LINK).seal(b"cmd")
    assert Verifier(SESSION, HOST_LINK).feed(old) == b""


def test_resynchronising_hashes_each_byte_at_most_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """Garbage made of record headers that each claim 4 KB: a receiver that hashed a claimed
    record and stepped one byte on hashed ~300 times every byte (bench/bench_signing.py)."""
    hashed = [0]
    real = signing.hmac_sha256

    def counting(key: bytes, data: bytes) -> bytes:
        hashed[0] += len(data)
        return real(key, data)

    monkeypatch.setattr(signing, "hmac_sha256", counting)
    head = MAGIC + bytes((HOST_LINK,)) + bytes(6) + struct.pack("<H", MAX_DATA)
    garbage = (head * 2000)[:20_000] + random.Random(3).randbytes(20_000)
    v = Verifier(SESSION, HOST_LINK)
    for i in range(0, len(garbage), 512):
        v.feed(garbage[i : i + 512])
    assert hashed[0] <= len(garbage)
    assert v.feed(Signer(SESSION, HOST_LINK).seal(b"on")) == b"on"  # and it goes on


def test_urls_and_keys(tmp_path: Path) -> None:
    with pytest.raises(BadURL, match="needs \\?key=FILE"):
        check_url("signed+tcp://127.0.0.1:5000")
    with pytest.raises(BadURL, match=r"signing key .*: 32 bytes"):
        (tmp_path / "bad.key").write_text("short")
        check_url(f"signed+tcp://127.0.0.1:5000?key={tmp_path}/bad.key")
    (tmp_path / "k").write_text(KEY.hex() + "\n")
    assert check_url(f"signed+tcp://127.0.0.1:5000?key={tmp_path}/k") == "tcp"


# ---- the board's side: who is its host -------------------------------------------------------
class FakeServer:
    """link.py's TcpServer interface over connections a test makes (a fake: no sockets)."""

    def __init__(self) -> None:
        self.new: list[int] = []
        self.rx: dict[int, bytearray] = {}
        self.sent: dict[int, bytearray] = {}
        self.closed: set[int] = set()
        self.count = 0

    def connect(self) -> int:
        self.count += 1
        n = self.count
        self.new.append(n)
        self.rx[n], self.sent[n] = bytearray(), bytearray()
        return n

    def accept(self) -> int | None:
        return self.new.pop(0) if self.new else None

    def recv(self, n: int) -> bytes | None:
        if n in self.closed:
            return b""
        data, self.rx[n] = bytes(self.rx[n]), bytearray()
        return data or None

    def send(self, n: int, data: bytes) -> bool:
        if n in self.closed:
            return False
        self.sent[n] += data
        return True

    def drop(self, n: int) -> None:
        self.closed.add(n)

    def wait(self, us: int) -> None:
        pass

    def close(self) -> None:
        pass


class Client:
    """A host on a FakeServer connection: its hello, the board's challenge, its records."""

    def __init__(self, server: FakeServer, key: bytes = KEY) -> None:
        self.server, self.key = server, key
        self.n = server.connect()
        self.nonce = random.randbytes(16)
        server.rx[self.n] += hello(key, self.nonce)
        self.signer: Signer | None = None

    def session(self) -> Signer:
        got = bytes(self.server.sent[self.n])
        assert got[4] == CHALLENGE and got[13:29] == self.nonce, got
        self.signer = self.signer or Signer(session_key(self.key, self.nonce, got[29:45]), 0)
        return self.signer

    def send(self, data: bytes) -> None:
        self.server.rx[self.n] += self.session().seal(data)


def board_link(now: list[int]) -> tuple[FakeServer, SignedLink]:
    server = FakeServer()
    return server, SignedLink(server, KEY, lambda: now[0], random.randbytes)


def test_a_new_connection_takes_over_only_once_it_has_proven_the_key() -> None:
    now = [0]
    server, link = board_link(now)
    host = Client(server)
    assert link.read() is None  # its hello: answered with a challenge
    host.send(b"request")
    assert link.read() == b"request" and link.host == host.n
    # clients without the key, again and again: none of them moves the host
    for k in range(50):
        intruder = Client(server, key=bytes(32))
        link.read()
        if k % 3 == 0:
            server.rx[intruder.n] += seal(bytes(32), HOST_LINK, 1, b"cmd")  # (its own key)
        elif k % 3 == 1:
            server.rx[intruder.n] += encode_frame(SOF, 1, 3, b"")  # plain J2A
        else:
            server.rx[intruder.n] += host.session().seal(b"stolen")[:-1] + b"\0"
        host.send(b"still here")
        assert link.read() == b"still here" and link.host == host.n
    assert host.n not in server.closed
    assert link.stats()["unproven"] == 50 and link.stats()["bad_tags"] == 50 + 17 + 16
    link.write(b"reply")
    assert (
        Verifier(session_key(KEY, host.nonce, server.sent[host.n][29:45]), BOARD_LINK).feed(
            bytes(server.sent[host.n][45:])
        )
        == b"reply"
    )
    # the host reconnects: its new connection proves the key, the old one is closed
    again = Client(server)
    link.read()
    assert link.host == host.n
    again.send(b"hello again")
    assert link.read() == b"hello again" and link.host == again.n and host.n in server.closed


def test_connections_that_do_not_prove_the_key_are_closed() -> None:
    now = [0]
    server, link = board_link(now)
    silent = [server.connect() for _ in range(3)]
    link.read()
    assert not server.closed
    newest = server.connect()  # one more than MAX_PENDING: the oldest goes
    link.read()
    assert server.closed == {silent[0]}
    now[0] = SignedLink.PENDING_MS + 1  # and the others when their time is up
    link.read()
    assert server.closed == {*silent, newest}
    late = Client(server)  # a host after all that: taken
    link.read()
    late.send(b"x")
    assert link.read() == b"x"
    assert link.stats()["unproven"] == 4


def test_a_hello_with_another_key_is_answered_and_counted() -> None:
    """The board answers every hello, so a host with another key can say so by name."""
    server, link = board_link([0])
    wrong = Client(server, key=bytes(32))
    link.read()
    got = bytes(server.sent[wrong.n])
    assert got[4] == CHALLENGE and link.stats()["bad_tags"] == 1
    assert got[-8:] != hmac.new(bytes(32), got[:-8], hashlib.sha256).digest()[:8]


@pytest.mark.slow
def test_keys_are_made_and_put_on_boards_over_usb_only(tmp_path: Path) -> None:
    import os
    import stat

    key = tmp_path / "robot.key"
    r = ml("key", "new", str(key), timeout=30)
    assert r.returncode == 0 and len(bytes.fromhex(key.read_text().strip())) == 32
    assert stat.S_IMODE(os.stat(key).st_mode) == 0o600
    r = ml("key", "new", str(key), timeout=30)
    assert r.returncode == 2 and "exists" in r.stderr
    flash = ("flash", str(WIFI), "--dry-run")
    r = ml(*flash, timeout=30)
    assert r.returncode != 0 and "give the key with --key" in r.stderr
    r = ml(*flash, "--key", str(key), timeout=30)
    assert r.returncode == 0 and f"{key} -> :mlkey.bin" in r.stdout, r.stderr
    r = ml(*flash, "--key", str(key), "--port", "tcp://10.0.0.5:5000", timeout=30)
    assert r.returncode != 0 and "over USB only" in r.stderr and r.stderr.count("\n") == 1
