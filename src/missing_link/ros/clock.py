"""The clock record: one message per ``a2jClock`` exchange of a board, with the clock map after
it, so that a recording can be audited (how good was the map, when did the board reset) or
re-timed offline (feed the exchanges to :class:`~missing_link.timesync.ClockSync` again).  Pure:
a record in, CDR bytes out, checked against rosbags by the tests.

Recorded as ``/<board>/clock`` (``/<board>/clock_sync`` when a transducer is called ``clock``)
with the type ``missing_link_msgs/msg/ClockExchange``; every host time is CLOCK_REALTIME ns, the
time base samples are published in.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ..timesync.estimator import Estimate
    from ..timesync.exchange import Exchange

CLOCK_TYPE = "missing_link_msgs/msg/ClockExchange"
CLOCK_MSG = """\
# One a2jClock exchange of a board and the clock map after it (missing-link clock sync).
# Host times are CLOCK_REALTIME ns, the time base samples are published in.
int64 t1_ns           # host: just before the request was written
uint64 t2_us          # board: when the request had arrived
uint64 t3_us          # board: just before the reply's first byte was sent
int64 t4_ns           # host: by when the reply had arrived
int64 up_min_ns       # delay known to be in the request (its bytes on a UART), else 0
int64 down_min_ns     # delay known to be in the reply between t3 and t4, else 0
uint64 board_us       # the estimate after this exchange maps this board time ...
int64 host_ns         # ... to this host time
float64 skew_ppm      # the board clock's rate error (positive: it runs fast)
float64 bound_ns      # hard: the truth is within +-bound_ns at board_us (-1: no estimate)
float64 est_error_ns  # statistical: the error's typical size at board_us (-1: no estimate)
uint32 points         # exchanges in the estimator's window
string clock_epoch    # the board's clock.epoch: a new one means the board restarted
uint8 result          # 0 accepted, 1 refused (malformed or an outlier), 2 the board reset
"""

ACCEPTED, REFUSED, RESET = 0, 1, 2

_HEAD = struct.Struct("<4s qQQqqq Qq ddd I")  # (CDR header) ... points


@dataclass(frozen=True)
class ClockRecord:
    t1_ns: int
    t2_us: int
    t3_us: int
    t4_ns: int
    up_min_ns: int
    down_min_ns: int
    board_us: int
    host_ns: int
    skew_ppm: float
    bound_ns: float
    est_error_ns: float
    points: int
    clock_epoch: str
    result: int


def record_of(
    ex: Exchange, result: int, est: Estimate | None, realtime_offset_ns: int, epoch: str
) -> ClockRecord:
    """The record of one exchange (its host stamps moved to CLOCK_REALTIME) and of the
    estimate after it (``None``: none yet; its numbers are then 0 and -1)."""
    off = realtime_offset_ns
    if est is None:
        b, h, skew, bound, err, points = 0, 0, 0.0, -1.0, -1.0, 0
    else:
        b, h, skew = est.b_ref, round(est.h_ref) + off, (1000.0 / est.rate - 1.0) * 1e6
        bound, err, points = max(-est.lo_ns, est.hi_ns), est.est_error_ns(b), est.points
    return ClockRecord(
        ex.t1 + off,
        ex.t2,
        ex.t3,
        ex.t4 + off,
        ex.up_min_ns,
        ex.down_min_ns,
        b,
        h,
        skew,
        bound,
        err,
        points,
        epoch,
        result,
    )


def clock_topic(board: str, transducers: set[str]) -> str:
    """The record's topic for a board whose transducers are named ``transducers``."""
    return f"/{board}/clock_sync" if "clock" in transducers else f"/{board}/clock"


def clock_record_cdr(r: ClockRecord) -> bytes:
    """``r`` as ROS 2 CDR (little endian): the fields in message order, 8-byte ones first, so
    only the string's own alignment applies."""
    epoch = r.clock_epoch.encode("utf-8", "replace") + b"\0"
    return (
        _HEAD.pack(
            b"\x00\x01\x00\x00",
            r.t1_ns,
            r.t2_us,
            r.t3_us,
            r.t4_ns,
            r.up_min_ns,
            r.down_min_ns,
            r.board_us,
            r.host_ns,
            r.skew_ppm,
            r.bound_ns,
            r.est_error_ns,
            r.points,
        )
        + struct.pack("<I", len(epoch))
        + epoch
        + bytes((r.result,))
    )


def clock_record_from_cdr(data: bytes) -> ClockRecord:
    """The record ``clock_record_cdr`` made (a ValueError for bytes that are not one)."""
    try:
        head = _HEAD.unpack_from(data)
        (n,) = struct.unpack_from("<I", data, _HEAD.size)
        start = _HEAD.size + 4
        raw = data[start : start + n]
        if n < 1 or len(raw) != n or len(data) < start + n + 1 or raw[-1:] != b"\0":
            raise ValueError("clock record with a damaged epoch")
        result = data[start + n]
    except struct.error as e:
        raise ValueError(f"clock record: {e}") from None
    if head[0][:2] != b"\x00\x01":
        raise ValueError("clock record: not little-endian CDR")
    t1, t2, t3, t4, up, down, b, h, skew, bound, err, points = head[1:]
    epoch = raw[:-1].decode("utf-8", "replace")
    return ClockRecord(t1, t2, t3, t4, up, down, b, h, skew, bound, err, points, epoch, result)
