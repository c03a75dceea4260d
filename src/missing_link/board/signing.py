# Signed J2A records: the J2A bytes of a network link (a board on WiFi, TCP) authenticated in
# the spirit of MAVLink 2's signing (docs/signing.md has the bytes).
#
# Theory of operation
# -------------------
# Both ends hold the same 32-byte key, put on the board over USB only (`missing-link flash
# --key`) and never sent over the network.  Every write becomes one record:
#
#   magic "J2AS" (4) | link id (1) | timestamp (6, LE) | length (2, LE) | J2A bytes | tag (8)
#
# tag = the first 8 bytes of HMAC-SHA256(key, everything before the tag).  The J2A bytes inside
# are exactly what the unsigned link would carry (whole frames), so J2A itself is unchanged.
# The timestamp must grow with every record a sender sends: a receiver keeps the newest it has
# accepted per link id and drops a record whose timestamp is not newer (a replay), one whose tag
# does not check (altered, or signed with another key) and anything that is not a record
# (unsigned bytes), counting each (`replayed`, `bad_tags`, `junk`).  The host stamps in MAVLink's
# units, 10 µs since 2015-01-01 (its wall clock, kept increasing); a board, which has no wall
# clock, stamps (boot count << 32) + ms since boot, so a board that restarts still stamps newer
# than before (its boot count is kept in its flash).  The link id tells the two directions apart
# (host: 0, board: 1), so a record cannot be reflected back to its sender.
#
# Pure: time and keys are handed in.  MicroPython subset (hashlib.sha256; its hmac module is
# not on every port, so HMAC is spelled out).

import hashlib
import struct

MAGIC = b"J2AS"
HEAD = 13  # magic, link id, timestamp, length
TAG = 8
MAX_DATA = 4096
HOST_LINK = 0
BOARD_LINK = 1
_BLOCK = 64


def hmac_sha256(key, data):
    if len(key) > _BLOCK:
        key = hashlib.sha256(key).digest()
    key = key + bytes(_BLOCK - len(key))
    inner = hashlib.sha256(bytes(b ^ 0x36 for b in key) + data).digest()
    return hashlib.sha256(bytes(b ^ 0x5C for b in key) + inner).digest()


class Signer:
    # seal(data, now) -> one record; `now` is the sender's clock in its units (see above)
    def __init__(self, key, link_id):
        if len(key) != 32:
            raise ValueError("a signing key has 32 bytes")
        self.key = key
        self.link_id = link_id
        self._last = 0

    def seal(self, data, now):
        if len(data) > MAX_DATA:
            raise ValueError("record of %d bytes: at most %d" % (len(data), MAX_DATA))
        ts = now if now > self._last else self._last + 1  # strictly growing
        self._last = ts
        head = MAGIC + bytes((self.link_id,)) + _u48(ts) + struct.pack("<H", len(data))
        body = head + bytes(data)
        return body + hmac_sha256(self.key, body)[:TAG]


class Verifier:
    # feed(bytes) -> the J2A bytes of the records that check, in order
    def __init__(self, key, link_id):
        self.key = key
        self.link_id = link_id  # the sender's: records from anyone else are not ours
        self.newest = -1
        self.records = 0
        self.bad_tags = 0
        self.replayed = 0
        self.junk = 0
        self._buf = b""

    def feed(self, data):
        buf = self._buf + bytes(data)
        out = []
        while buf:
            i = buf.find(MAGIC)
            if i < 0:
                keep = _partial_magic(buf)
                self.junk += len(buf) - keep
                buf = buf[len(buf) - keep :]
                break
            if i:
                self.junk += i
                buf = buf[i:]
            if len(buf) < HEAD:
                break
            n = struct.unpack("<H", buf[11:13])[0]
            if n > MAX_DATA:
                self.junk += 1  # not a record: look for the next magic
                buf = buf[1:]
                continue
            end = HEAD + n + TAG
            if len(buf) < end:
                break
            body, tag = buf[: HEAD + n], buf[HEAD + n : end]
            if buf[4] != self.link_id or hmac_sha256(self.key, body)[:TAG] != tag:
                self.bad_tags += 1
                buf = buf[1:]  # (resynchronise: the next magic may be a real record)
                continue
            buf = buf[end:]
            ts = _u48_of(body[5:11])
            if ts <= self.newest:
                self.replayed += 1
                continue
            self.newest = ts
            self.records += 1
            out.append(body[HEAD:])
        self._buf = buf
        return b"".join(out)

    def stats(self):
        return {
            "records": self.records,
            "bad_tags": self.bad_tags,
            "replayed": self.replayed,
            "junk": self.junk,
        }


def _u48(v):
    return bytes((v >> (8 * i)) & 0xFF for i in range(6))


def _u48_of(b):
    v = 0
    for i in range(5, -1, -1):
        v = (v << 8) | b[i]
    return v


def _partial_magic(buf):
    # how many bytes at the end of buf could begin a magic (kept for the next feed)
    for k in range(min(len(MAGIC) - 1, len(buf)), 0, -1):
        if MAGIC[:k] == buf[len(buf) - k :]:
            return k
    return 0


def host_now(unix_ns):
    # the host's timestamp: 10 µs units since 2015-01-01 UTC, as MAVLink 2's
    return (unix_ns - 1420070400000000000) // 10000


def board_now(boots, ms):
    # a board's timestamp: its boot count, then ms since boot
    return ((boots & 0xFFFF) << 32) | (ms & 0xFFFFFFFF)


class SignedLink:
    # The board's side: a link (link.py's) whose bytes travel in signed records.  Unsigned
    # bytes, altered or foreign records and replays are dropped and counted (stats(): the J2A
    # function a2jLinkStats).  `store` keeps the newest host timestamp across restarts (saved
    # when it has moved on by SAVE_EVERY, a minute of the host's clock), so a record replayed
    # after the board restarted is refused too, but for the last minute's.
    SAVE_EVERY = 6000000  # 10 µs units: 60 s

    def __init__(self, link, key, clock_ms, boots, store=None):
        self.link = link
        self._signer = Signer(key, BOARD_LINK)
        self._verifier = Verifier(key, HOST_LINK)
        self._clock_ms = clock_ms
        self._boots = boots
        self._store = store
        self._saved = -1
        if store is not None:
            v = store.load()
            if v is not None:
                self._verifier.newest = self._saved = v

    def read(self):
        data = self.link.read()
        if not data:
            return None
        out = self._verifier.feed(data)
        v = self._verifier.newest
        if self._store is not None and v - self._saved >= self.SAVE_EVERY:
            self._store.save(v)
            self._saved = v
        return out or None

    def write(self, data):
        self.link.write(self._signer.seal(data, board_now(self._boots, self._clock_ms())))

    def wait(self, us):
        self.link.wait(us)

    def close(self):
        self.link.close()

    def stats(self):
        return self._verifier.stats()
