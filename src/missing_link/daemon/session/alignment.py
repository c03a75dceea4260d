"""One board's sampling on the host-time grid, seen from the daemon (board/timing.py;
docs/timesync.md, "Measuring together, acting on time").

The grid of an aligned transducer follows from its configuration: the period is 1 / ``rate_hz``
in whole µs (as the board computes it: ``int(1e6 / rate_hz)``), offset by ``phase`` periods,
counted in host ns since the epoch (CLOCK_REALTIME, the time samples are published in).  The
sample path flags a sample that is not on it (``OFF_GRID``).  An ultrasonic ranger's ping is
on the grid but its sample is stamped when the echo reflected, up to ECHO_LAG_NS later (half
the flight to 6 m and back), so its stamps may lag the grid by that much.  The board's own account
(``a2jAlignInfo``: whether its map is valid, its age, the samples it took without one, the
timed calls it did and refused) is read once per diagnostics period while anything is aligned,
in the background (never waited for: the session's supervisor must not be held up).
"""

from __future__ import annotations

import struct
from collections.abc import Mapping

from ...host.config import Value
from ...topics import Topic
from .status import AlignInfo


def _f32(x: float) -> float:
    return float(struct.unpack("<f", struct.pack("<f", x))[0])


#: how far after its grid instant an ultrasonic ranger's stamp may lie: its ping starts on the
#: instant, its stamp is half the echo's flight later (6 m, the SRF02's reach: 17.5 ms)
ECHO_LAG_NS = 18_000_000


def grid_of(
    values: Mapping[str, Value], topics: Mapping[int, Topic]
) -> dict[int, tuple[int, int, int]]:
    """Transducer id -> (period ns, phase ns, lag ns: how late a stamp may be after its
    instant) for every aligned transducer with a rate."""
    out: dict[int, tuple[int, int, int]] = {}
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
        lag = ECHO_LAG_NS if topic.transducer.prefix == "ultrasonic" else 0
        out[tid] = (period, offset, min(lag, period // 2))
    return out


def off_grid(host_ns: int, grid: tuple[int, int, int], bound_ns: int, slack_ns: int) -> bool:
    """Whether a stamp is further from its grid instant than its bound (and ``slack_ns``)
    allow: before the instant, or after it by more than the grid's lag."""
    period, phase, lag = grid
    off = (host_ns - phase) % period  # after its instant; period - off: before the next
    return off > lag + bound_ns + slack_ns and period - off > bound_ns + slack_ns


def parse_align_info(p: bytes) -> AlignInfo:
    """``a2jAlignInfo``'s reply: whether the board's map is valid and its age, its samples not
    on the grid, its timed calls done and refused; a Python board's also its free-running
    measurements put off for an instant and its polls that reached one (board/pacing.py)."""
    if len(p) not in (17, 25):
        return AlignInfo(problem=f"a reply of {len(p)} bytes, not 17 or 25")
    valid, age, unaligned, done, refused = struct.unpack("<BIIII", p[:17])
    deferred, overlaps = struct.unpack("<II", p[17:]) if len(p) == 25 else (None, None)
    return AlignInfo(
        map_valid=bool(valid),
        map_age_ms=None if age == 0xFFFFFFFF else age,
        unaligned_samples=unaligned,
        timed_done=done,
        timed_refused=refused,
        polls_deferred=deferred,
        poll_overlaps=overlaps,
    )


def aligned(grid: Mapping[int, tuple[int, int, int]], topics: Mapping[int, Topic]) -> str:
    """The aligned transducers by name (the status's ``aligned``)."""
    return ", ".join(topics[tid].transducer.name for tid in grid if tid in topics)
