# Signed J2A records: the J2A bytes of a network link (a board on WiFi, TCP) authenticated in
# the spirit of MAVLink 2's signing, with a per-connection challenge in place of its clock
# (docs/signing.md has the bytes).
#
# Theory of operation
# -------------------
# Both ends hold the same 32-byte key, put on the board over USB only (`missing-link flash
# --key`) and never sent over the network.  Everything on the link is a record:
#
#   magic "J2AS" (4) | kind (1) | counter (6, LE) | length n (2, LE) | n bytes | tag (8)
#
# tag = the first 8 bytes of HMAC-SHA256(a key, everything before the tag).  A connection opens
# with a handshake that needs no clock on either side:
#
#   host -> board  HELLO      kind 2, counter 0, data: Nh, 16 fresh random bytes; tag: the key
#   board -> host  CHALLENGE  kind 3, counter 0, data: Nh + Nb, 16 fresh bytes of the board's;
#                             tag: the key
#
# and both derive the session key S = HMAC-SHA256(key, "J2AK" + Nh + Nb).  J2A then travels in
# DATA records tagged with S: kind 0 from the host, 1 from the board, each side counting 1, 2,
# 3...  A receiver takes a DATA record only when its tag checks under S and its counter is
# beyond the newest it took; everything else is dropped and counted: a record of another
# connection (another Nh or Nb, so another S: a replay), an old one of this connection
# (`replayed`), an altered or foreign one, or one sent back to its sender (the other kind: a
# reflection) (`bad_tags`), bytes that are no record (`junk`).  The host checks the CHALLENGE
# under the key (another key: "the board's key differs", by name) and that it carries its own
# Nh (an old challenge replayed is refused).  Nothing of this depends on a wall clock, and
# nothing is kept across connections or restarts but the key.
#
# The board's side (SignedLink) serves the connections of a server (link.py's TcpServer):
# a new connection is answered its challenge and becomes the board's host only when its first
# DATA record checks (it has proven the key); until then the host that proved it keeps the
# link, and a client without the key can connect as often as it likes without moving it.  A
# new connection that sends anything else first, or nothing for PENDING_MS, is closed; at most
# MAX_PENDING wait at once (the oldest is closed for a newer one).
#
# Resynchronisation costs one pass: a record whose tag does not check is skipped whole (its
# length says how far), so every byte received is hashed at most once, whatever the garbage.
# (Records travel on reliable streams, TCP or a unix socket: a bad record there is an
# attacker's, not line noise, and what follows its claimed end is the next record.)
#
# Pure: keys, nonces and the clock are handed in.  MicroPython subset (hashlib.sha256; its hmac
# module is not on every port, so HMAC is spelled out).

import hashlib
import struct

MAGIC = b"J2AS"
HEAD = 13  # magic, kind, counter, length
TAG = 8
MAX_DATA = 4096
NONCE = 16
HOST_LINK = 0  # DATA from the host
BOARD_LINK = 1  # DATA from the board
HELLO = 2
CHALLENGE = 3
_BLOCK = 64


def hmac_sha256(key, data):
    if len(key) > _BLOCK:
        key = hashlib.sha256(key).digest()
    key = key + bytes(_BLOCK - len(key))
    inner = hashlib.sha256(bytes(b ^ 0x36 for b in key) + data).digest()
    return hashlib.sha256(bytes(b ^ 0x5C for b in key) + inner).digest()


def seal(key, kind, counter, data):
    # one record of `data`
    if len(data) > MAX_DATA:
        raise ValueError("record of %d bytes: at most %d" % (len(data), MAX_DATA))
    body = MAGIC + bytes((kind,)) + _u48(counter) + struct.pack("<H", len(data)) + bytes(data)
    return body + hmac_sha256(key, body)[:TAG]


def checks(key, rec):
    # whether a record (from Splitter) carries the tag of `key`
    return hmac_sha256(key, rec[3])[:TAG] == rec[4]


def session_key(key, host_nonce, board_nonce):
    return hmac_sha256(key, b"J2AK" + host_nonce + board_nonce)


def hello(key, host_nonce):
    return seal(key, HELLO, 0, host_nonce)


def challenge(key, host_nonce, board_nonce):
    return seal(key, CHALLENGE, 0, host_nonce + board_nonce)


class Splitter:
    # feed(bytes) -> the whole records in them, each (kind, counter, data, body, tag); bytes
    # that begin no record are counted in `junk` (and kept in `skipped`, up to its cap, when it
    # is a bytearray: the host looks there for plain J2A).  A header whose length is over
    # MAX_DATA is no record either.
    def __init__(self):
        self.junk = 0
        self.skipped = None
        self._buf = b""

    def _skip(self, b):
        self.junk += len(b)
        s = self.skipped
        if s is not None and len(s) < 1024:
            s.extend(b[: 1024 - len(s)])

    def feed(self, data):
        buf = self._buf + bytes(data)
        out = []
        while buf:
            i = buf.find(MAGIC)
            if i < 0:
                keep = _partial_magic(buf)
                self._skip(buf[: len(buf) - keep])
                buf = buf[len(buf) - keep :]
                break
            if i:
                self._skip(buf[:i])
                buf = buf[i:]
            if len(buf) < HEAD:
                break
            n = buf[11] | (buf[12] << 8)
            if n > MAX_DATA:
                self._skip(buf[:1])  # not a record: look for the next magic
                buf = buf[1:]
                continue
            end = HEAD + n + TAG
            if len(buf) < end:
                break
            body = buf[: HEAD + n]
            out.append((buf[4], _u48_of(buf, 5), body[HEAD:], body, buf[HEAD + n : end]))
            buf = buf[end:]
        self._buf = buf
        return out


class Signer:
    # seal(data) -> one DATA record of this side (`link_id`), its counter one more each time
    def __init__(self, key, link_id):
        if len(key) != 32:
            raise ValueError("a signing key has 32 bytes")
        self.key = key
        self.link_id = link_id
        self.counter = 0

    def seal(self, data):
        self.counter += 1
        return seal(self.key, self.link_id, self.counter, data)


class Verifier:
    # feed(bytes) -> the J2A bytes of the DATA records from `link_id` (the sender's) that check
    # under `key` with a growing counter, in order.  `took` counts the records it took,
    # `dropped` those it did not; `counts` (shared by a board's connections) has every kind.
    def __init__(self, key, link_id, counts=None, split=None):
        self.key = key
        self.link_id = link_id
        self.newest = 0
        self.took = 0
        self.dropped = 0
        self.counts = counts if counts is not None else new_counts()
        self.split = split if split is not None else Splitter()

    def feed(self, data):
        junk = self.split.junk
        out = self.take(self.split.feed(data))
        self.counts["junk"] += self.split.junk - junk
        return out

    def take(self, recs):
        c = self.counts
        out = []
        for rec in recs:
            if rec[0] != self.link_id or not checks(self.key, rec):
                c["bad_tags"] += 1
                self.dropped += 1
            elif rec[1] <= self.newest:
                c["replayed"] += 1
                self.dropped += 1
            else:
                self.newest = rec[1]
                self.took += 1
                c["records"] += 1
                out.append(rec[2])
        return b"".join(out)

    def stats(self):
        return dict(self.counts)


def new_counts():
    return {"records": 0, "bad_tags": 0, "replayed": 0, "junk": 0, "unproven": 0}


def _u48(v):
    return bytes((v >> (8 * i)) & 0xFF for i in range(6))


def _u48_of(b, at):
    v = 0
    for i in range(at + 5, at - 1, -1):
        v = (v << 8) | b[i]
    return v


def _partial_magic(buf):
    # how many bytes at the end of buf could begin a magic (kept for the next feed)
    for k in range(min(len(MAGIC) - 1, len(buf)), 0, -1):
        if MAGIC[:k] == buf[len(buf) - k :]:
            return k
    return 0


class _Pending:
    # a connection that has not proven the key yet
    def __init__(self, since):
        self.since = since
        self.split = Splitter()
        self.verifier = None  # once its HELLO is answered: its session's


class SignedLink:
    # The board's side: the connections of `server` (link.py's TcpServer: accept() -> n,
    # recv(n) -> bytes / None (nothing yet) / b"" (closed), send(n, data) -> bool, drop(n),
    # wait(us), close()) as one link to the host that proved the key (see the theory above).
    # `nonce(n)` gives n fresh random bytes, `clock_ms()` the board's ms.  stats(): the J2A
    # function a2jLinkStats, plus `unproven` (connections closed before they proved the key).
    MAX_PENDING = 3
    PENDING_MS = 5000

    def __init__(self, server, key, clock_ms, nonce):
        if len(key) != 32:
            raise ValueError("a signing key has 32 bytes")
        self.server = server
        self.key = key
        self._clock_ms = clock_ms
        self._nonce = nonce
        self.counts = new_counts()
        self._pending = {}
        self.host = None  # the connection that proved the key
        self._verifier = None
        self._signer = None

    def read(self):
        now = self._clock_ms()
        self._accept(now)
        out = []
        for n in list(self._pending):
            if now - self._pending[n].since > self.PENDING_MS:
                self._refuse(n)
                continue
            data = self.server.recv(n)
            if data is None:
                continue
            if not data:  # closed by the client
                self._pending.pop(n)
                self.counts["unproven"] += 1
            else:
                out.append(self._proving(n, data))
        if self.host is not None:
            data = self.server.recv(self.host)
            if data:
                out.append(self._verifier.feed(data))
            elif data is not None:  # the host closed: wait for the next to prove the key
                self.host = None
        data = b"".join(out)
        return data or None

    def _accept(self, now):
        while True:
            n = self.server.accept()
            if n is None:
                return
            self._pending[n] = _Pending(now)
            if len(self._pending) > self.MAX_PENDING:
                oldest = None
                for k in self._pending:
                    if oldest is None or self._pending[k].since < self._pending[oldest].since:
                        oldest = k
                self._refuse(oldest)

    def _refuse(self, n):
        self._pending.pop(n, None)
        self.server.drop(n)
        self.counts["unproven"] += 1

    def _proving(self, n, data):
        # a new connection's bytes: a HELLO first, then DATA records; the first that checks
        # makes it the host, anything else before that closes it
        p = self._pending[n]
        junk = p.split.junk
        recs = p.split.feed(data)
        self.counts["junk"] += p.split.junk - junk
        if p.split.junk != junk:
            self._refuse(n)  # bytes that are no record: not a host of ours
            return b""
        if p.verifier is None:
            if not recs:
                return b""  # (the rest of the HELLO is on its way)
            if not self._answer(n, p, recs.pop(0)):
                return b""
        out = p.verifier.take(recs)
        if p.verifier.took:
            self._pending.pop(n)
            if self.host is not None:
                self.server.drop(self.host)
            self.host, self._verifier = n, p.verifier
            self._signer = Signer(p.verifier.key, BOARD_LINK)
            return out
        if p.verifier.dropped:
            self._refuse(n)
        return b""

    def _answer(self, n, p, rec):
        if rec[0] != HELLO or len(rec[2]) != NONCE:
            self._refuse(n)
            return False
        if not checks(self.key, rec):
            self.counts["bad_tags"] += 1  # (answered all the same: the host names the mismatch)
        nb = self._nonce(NONCE)
        if not self.server.send(n, challenge(self.key, rec[2], nb)):
            self._pending.pop(n, None)
            self.counts["unproven"] += 1
            return False
        p.verifier = Verifier(session_key(self.key, rec[2], nb), HOST_LINK, self.counts, p.split)
        return True

    def write(self, data):
        if self.host is None:
            return  # nobody has proven the key: like a UART with nothing attached
        if not self.server.send(self.host, self._signer.seal(data)):
            self.host = None

    def wait(self, us):
        self.server.wait(us)

    def close(self):
        self.server.close()

    def stats(self):
        return dict(self.counts)
