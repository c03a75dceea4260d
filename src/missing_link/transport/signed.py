"""``signed+URL?key=FILE``: J2A over a network link in signed records (board/signing.py;
docs/signing.md).  Every write is sealed with the key (the host's link id, its timestamp); what
the board sends is verified, and anything that does not check - unsigned bytes, an altered or
foreign record, a replay - is dropped and counted (``link_stats``: the daemon shows them).

The key file holds the 32-byte key (raw, or 64 hex digits); it reached the board over USB
(``missing-link flash --key``).  The newest timestamp seen from a board is kept per key for the
life of the process, so a board's old records replayed into a new connection are dropped too.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

from ..board.signing import BOARD_LINK, HOST_LINK, Signer, Verifier, host_now
from ..errors import BadURL
from .base import Received, Transport

#: key digest -> the newest board timestamp accepted in this process (replays across reconnects)
_NEWEST: dict[bytes, int] = {}
_NEWEST_LOCK = threading.Lock()


def load_key(path: str) -> bytes:
    p = Path(path).expanduser()
    try:
        raw = p.read_bytes()
    except OSError as e:
        raise BadURL(f"signing key {path}: {e.strerror or e}") from None
    text = raw.strip()
    if len(text) == 64:
        try:
            return bytes.fromhex(text.decode())
        except ValueError:
            pass
    if len(raw) == 32:
        return raw
    raise BadURL(f"signing key {path}: 32 bytes, or 64 hex digits (missing-link key new)")


class SignedTransport(Transport):
    def __init__(self, inner: Transport, key: bytes) -> None:
        self.inner = inner
        self.url = "signed+" + inner.url
        self._signer = Signer(key, HOST_LINK)
        self._verifier = Verifier(key, BOARD_LINK)
        self._wlock = threading.Lock()
        self._id = __import__("hashlib").sha256(key).digest()
        with _NEWEST_LOCK:
            self._verifier.newest = _NEWEST.get(self._id, -1)

    def read(self, timeout: float | None) -> bytes:
        return self.read_stamped(timeout)[0]

    def read_stamped(self, timeout: float | None) -> Received:
        data, rx_ns, first_rx_ns = self.inner.read_stamped(timeout)  # (the inner link's stamps)
        if not data:
            return data, rx_ns, first_rx_ns
        out: bytes = self._verifier.feed(data)
        if self._verifier.newest >= 0:
            with _NEWEST_LOCK:
                _NEWEST[self._id] = max(_NEWEST.get(self._id, -1), self._verifier.newest)
        return out, rx_ns, first_rx_ns

    def write(self, data: bytes) -> None:
        with self._wlock:
            self.inner.write(self._signer.seal(data, host_now(time.time_ns())))

    def write_frames(self, frames: list[bytes]) -> None:
        with self._wlock:  # one record per frame: a lost record costs one frame
            now = host_now(time.time_ns())
            self.inner.write(b"".join(self._signer.seal(f, now) for f in frames))

    def link_stats(self) -> dict[str, int]:
        """What was dropped on the way in: ``signed_bad_tags``, ``signed_replayed``,
        ``signed_junk`` (unsigned bytes), and the records that checked."""
        return {f"signed_{k}": v for k, v in self._verifier.stats().items()}

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
