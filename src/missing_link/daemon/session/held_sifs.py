"""The SIFs a handshake holds between the sample path's ``listen`` and ``resume``
(sample_path.py), in order, at most ``HOLD_MAX``: past it they are dropped, and their number,
their seqs' span and the last one's seq are kept for the sample path to count them lost and go
on from them.  The reading thread holds; the supervisor's thread takes, under ``lock``."""

from __future__ import annotations

import threading

from ...j2a import SifReceived

#: SIFs held at most (64 Ki, some 12 MB): a board that keeps sending while its count call keeps
#: timing out grew them with every failed handshake (200 of 1000 SIFs: 37 MB, none published)
HOLD_MAX = 65_536


class HeldSifs:
    def __init__(self) -> None:
        self.sifs: list[tuple[SifReceived, float]] | None = None  #: None: not in a handshake
        self.lock = threading.Lock()
        self.dropped = 0  #: dropped past ``HOLD_MAX``, not yet counted lost
        self.span = 0  #: the dropped ones' seqs: each one and the gap before it
        self.last_seq: int | None = None  #: the last one dropped's seq (the seq goes on from it)

    def hold(self, sif: SifReceived, now_mono: float) -> bool:
        """Between ``listen`` and ``resume``: the SIF waits, or past ``HOLD_MAX`` is dropped
        and counted (True)."""
        with self.lock:
            if self.sifs is None:
                return False
            if len(self.sifs) < HOLD_MAX:
                self.sifs.append((sif, now_mono))
            else:
                self.dropped += 1
                self.span += 1 + sif.lost
                self.last_seq = sif.seq
            return True

    def count_before(self, count: int | None) -> int | None:
        """``count`` as if read just before the first SIF held: it was read after them (and
        after those a failed handshake left, and those dropped), so it counts each one and the
        gap before it; left in, their number over 128 read as a wrap of the seq lost."""
        with self.lock:
            held = self.sifs
            if count is None or not held:
                return count
            return count - sum(1 + sif.lost for sif, _ in held) - self.span + held[0][0].lost

    def forget_dropped(self) -> None:
        """(Under ``lock``.)  The dropped ones are accounted for: held from scratch."""
        self.dropped, self.span, self.last_seq = 0, 0, None
