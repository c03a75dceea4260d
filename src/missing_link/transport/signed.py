"""``signed+URL?key=FILE``: J2A over a network link in signed records (board/signing.py;
docs/signing.md).  Opening one greets the board: a HELLO with a fresh random nonce, and the
board's CHALLENGE back (within ``GREETING_S``), signed with the key and carrying that nonce and
one of the board's; their session key then signs every write (one record per J2A frame) and
checks what the board sends.  Anything that does not check - unsigned bytes, an altered or
foreign record, a record of another connection (a replay) - is dropped and counted
(``link_stats``).  No wall clock is read: a host whose clock jumps connects as before.

A greeting that goes wrong is said by name: the board's key differs from ours (its challenge
does not check), the board speaks plain J2A (it has no key), or no answer at all.

The key file holds the 32-byte key (raw, or 64 hex digits); it reached the board over USB
(``missing-link flash --key``).
"""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path
from typing import Any

from ..board.signing import (
    BOARD_LINK,
    CHALLENGE,
    HOST_LINK,
    NONCE,
    Signer,
    Splitter,
    Verifier,
    checks,
    hello,
    session_key,
)
from ..descriptors import read_input_file
from ..errors import BadURL, TransportBroken
from ..j2a.codec import Frame, FrameDecoder
from .base import Received, Transport

#: seconds a new connection waits for the board's challenge
GREETING_S = 5.0


#: bytes a key file may have (64 hex digits and a newline, or 32 raw bytes: a little room)
MAX_KEY_FILE = 1024


def load_key(path: str) -> bytes:
    try:  # (capped, and a device or FIFO refused before it is read: /dev/zero never ends)
        raw = read_input_file(str(Path(path).expanduser()), MAX_KEY_FILE)
    except OSError as e:
        raise BadURL(f"signing key {path}: {e.strerror or e}") from None
    except ValueError as e:
        raise BadURL(f"signing key {path}: {e}") from None
    text = raw.strip()
    if len(text) == 64:
        try:
            return bytes.fromhex(text.decode())
        except ValueError:  # (not hex: 32 raw bytes, or the error below)
            pass
    if len(raw) == 32:
        return raw
    raise BadURL(f"signing key {path}: 32 bytes, or 64 hex digits (missing-link key new)")


def _plain_j2a(data: bytes) -> bool:
    """Whether bytes outside any record hold a whole, good J2A frame: a board without a key."""
    return any(isinstance(x, Frame) for x in FrameDecoder().feed(data))


class SignedTransport(Transport):
    def __init__(self, inner: Transport, key: bytes, greeting_s: float = GREETING_S) -> None:
        if len(key) != 32:
            raise BadURL("a signing key has 32 bytes")
        self.inner = inner
        self.url = "signed+" + inner.url
        self._wlock = threading.Lock()
        try:
            session, split, early = self._greet(key, greeting_s)
        except BaseException:  # (broad, raised again: a failed greeting must not leak the link)
            inner.close()
            raise
        self._signer = Signer(session, HOST_LINK)
        self._verifier = Verifier(session, BOARD_LINK, split=split)
        self._verifier.counts["replayed"] += self._stale
        self._early: bytes = self._verifier.take(early)

    def _greet(self, key: bytes, greeting_s: float) -> tuple[bytes, Splitter, list[Any]]:
        """HELLO out, the board's CHALLENGE in: the session key, the splitter (with what came
        after), the records that came with the challenge."""
        nonce = os.urandom(NONCE)
        self._stale = 0  # challenges that were not for this hello (replays), counted
        self.inner.write(hello(key, nonce))
        split = Splitter()
        split.skipped = bytearray()
        deadline = time.monotonic() + greeting_s
        while (left := deadline - time.monotonic()) > 0:
            data = self.inner.read(min(left, 0.25))
            recs = split.feed(data) if data else []
            if split.skipped and _plain_j2a(bytes(split.skipped)):
                raise TransportBroken(
                    f"{self.url}: the board answers in plain J2A, not in signed records: it has "
                    "no key (flash it with --key), or open it without signed+"
                )
            for i, rec in enumerate(recs):
                if rec[0] != CHALLENGE or len(rec[2]) != 2 * NONCE:
                    continue
                if not checks(key, rec):
                    raise TransportBroken(
                        f"{self.url}: the board's key differs from this host's (its challenge "
                        "does not check): put the same key on both (missing-link flash --key)"
                    )
                if rec[2][:NONCE] != nonce:
                    self._stale += 1  # an old challenge, replayed
                    continue
                return session_key(key, nonce, rec[2][NONCE:]), split, recs[i + 1 :]
        raise TransportBroken(
            f"{self.url}: no answer to the signed hello within {greeting_s:g} s: a board "
            "without a key ignores signed records (flash it with --key), and so does one "
            "flashed before signing version 2 (flash it again)"
        )

    def read(self, timeout: float | None) -> bytes:
        return self.read_stamped(timeout)[0]

    def read_stamped(self, timeout: float | None) -> Received:
        if self._early:  # (records that came with the board's challenge: no stamps of theirs)
            early, self._early = self._early, b""
            return early, 0, 0
        data, rx_ns, first_rx_ns = self.inner.read_stamped(timeout)  # (the inner link's stamps)
        if not data:
            return data, rx_ns, first_rx_ns
        out: bytes = self._verifier.feed(data)
        return out, rx_ns, first_rx_ns

    def write(self, data: bytes) -> None:
        with self._wlock:
            self.inner.write(self._signer.seal(data))

    def write_frames(self, frames: list[bytes]) -> None:
        with self._wlock:  # one record per frame: a lost record costs one frame
            self.inner.write(b"".join(self._signer.seal(f) for f in frames))

    def link_stats(self) -> dict[str, int]:
        """What was dropped on the way in: ``signed_bad_tags``, ``signed_replayed``,
        ``signed_junk`` (unsigned bytes), and the records that checked."""
        keys = ("records", "bad_tags", "replayed", "junk")
        return {f"signed_{k}": self._verifier.counts[k] for k in keys}

    # the inner transport's stamps and wake-ups (clock sync)
    @property
    def last_write_ns(self) -> int:  # type: ignore[override]
        return self.inner.last_write_ns

    @property
    def wakes_on_close(self) -> bool:  # type: ignore[override]
        return self.inner.wakes_on_close

    @property
    def count_arrivals(self) -> bool:
        return self.inner.count_arrivals

    @count_arrivals.setter
    def count_arrivals(self, value: bool) -> None:
        self.inner.count_arrivals = value

    def count_arrived(self, woke_ns: int = 0) -> None:
        self.inner.count_arrived(woke_ns)

    def poke(self) -> None:
        self.inner.poke()

    def close(self) -> None:
        self.inner.close()
