"""Samples: SIFs decoded with the board's transducer descriptors.

Host time: ``host_rx`` is when the SIF was received, on the board's clock (CLOCK_MONOTONIC s
unless it was given another), not a clock-synchronised time (the daemon maps board stamps through
clock sync: ``daemon/session/sample_path.py``); ``board_us`` is the board's own stamp from the
moment of measurement and is always exact.
"""

from __future__ import annotations

from typing import NamedTuple

from ..descriptors import Transducer
from ..j2a import SifReceived


class Sample(NamedTuple):
    board: str
    transducer: str
    channel: int
    value: int | float | None  #: None: the board sent the transducer's N/A value
    board_us: int
    host_rx: float
    lost: int  #: SIFs lost just before this one (from the SIF seq)

    def to_json(self) -> dict[str, object]:
        return self._asdict()


class SampleDecoder:
    """Turns SIFs of one board into samples.  Unknown cmds and bad sizes are counted, not raised."""

    def __init__(self, board: str, transducers: list[Transducer]) -> None:
        self.board = board
        self.by_id = {t.id: t for t in transducers}
        self.unknown_cmd = 0
        self.bad_size = 0

    def decode(
        self, sif: SifReceived, host_rx: float, *, keep_missing: bool = True
    ) -> list[Sample]:
        t = self.by_id.get(sif.cmd)
        if t is None:
            self.unknown_cmd += 1
            return []
        try:
            values = t.decode(sif.payload)
        except ValueError:
            self.bad_size += 1
            return []
        return [
            Sample(self.board, t.name, ch, v, stamp, host_rx, sif.lost)
            for ch, (stamp, v) in enumerate(values)
            if keep_missing or v is not None
        ]
