"""One board's sampling on the host-time grid, seen from the daemon (board/timing.py;
docs/timesync.md, "Measuring together, acting on time").

The grid of an aligned transducer follows from its configuration: the period is 1 / ``rate_hz``
in whole µs (as the board computes it: ``int(1e6 / rate_hz)``), offset by ``phase`` periods,
counted in host ns since the epoch (CLOCK_REALTIME, the time samples are published in).  The
sample path flags a sample that is not on it (``OFF_GRID``); the board's own account
(``a2jAlignInfo``: whether its map is valid, its age, the samples it took without one, the
timed calls it did and refused) is read once per diagnostics period while anything is aligned.
"""

from __future__ import annotations

import struct
from collections.abc import Mapping
from typing import Any

from ..errors import MissingLinkError
from ..host.board import Board
from ..host.config import Value
from ..topics import Topic


def _f32(x: float) -> float:
    return float(struct.unpack("<f", struct.pack("<f", x))[0])


def grid_of(values: Mapping[str, Value], topics: Mapping[int, Topic]) -> dict[int, tuple[int, int]]:
    """Transducer id -> (period ns, phase ns) for every aligned transducer with a rate."""
    out: dict[int, tuple[int, int]] = {}
    for tid, topic in topics.items():
        t = topic.transducer.name
        rate = values.get(f"{t}.rate_hz")
        if values.get(f"{t}.aligned") is not True or not isinstance(rate, (int, float)):
            continue
        if rate <= 0:
            continue
        period = int(1e6 / _f32(float(rate))) * 1000  # the board's float32 and whole µs
        phase = values.get(f"{t}.phase", 0.0)
        offset = int(_f32(float(phase)) * period) % period if isinstance(phase, float) else 0
        out[tid] = (period, offset)
    return out


class Alignment:
    def __init__(self) -> None:
        self.info: dict[str, Any] = {}

    def refresh(self, board: Board) -> None:
        if "a2jAlignInfo" not in board.index:
            return
        try:
            p = board.call_ok("a2jAlignInfo")
        except MissingLinkError:
            return
        if len(p) != 17:
            self.info = {"align_info": f"a reply of {len(p)} bytes, not 17"}
            return
        valid, age, unaligned, done, refused = struct.unpack("<BIIII", p)
        self.info = {
            "map_valid": bool(valid),
            "map_age_ms": None if age == 0xFFFFFFFF else age,
            "unaligned_samples": unaligned,
            "timed_done": done,
            "timed_refused": refused,
        }

    def status(
        self, grid: Mapping[int, tuple[int, int]], topics: Mapping[int, Topic]
    ) -> dict[str, Any]:
        aligned = [topics[tid].transducer.name for tid in grid if tid in topics]
        return {"aligned": ", ".join(aligned), **(self.info if aligned else {})}
