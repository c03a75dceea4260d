"""``sensor_msgs/msg/NavSatFix`` and ``sensor_msgs/msg/TimeReference`` from ``gps_nmea``'s
channels: 0 latitude, 1 longitude (int32, 1e-7 degree), 2 altitude (mm above MSL), 3 GGA fix
quality, 4 satellites, 5 HDOP x 100, 6 speed (mm/s), 7 course (0.01 degree) -- and, from
drivers that report the UTC of a PPS edge, 8 that edge's UTC day (days since 1970-01-01) and
9 its UTC time of day (ms); N/A unless the sample is stamped at a PPS edge.

NavSatFix: degrees and metres (NaN without a fix); status -1 without a fix, 0 GPS, 1
differential (quality 2), 2 RTK (4, 5); the position covariance approximated from the HDOP
(``(HDOP x 5 m)^2`` horizontally, twice that vertically: APPROXIMATED).
TimeReference, for each sample stamped at a PPS edge: ``header.stamp`` is that edge in host
time (clock sync: the PPS pin's interrupt, on the board's clock), ``time_ref`` the UTC second
it began, ``source`` "gps".  So a consumer reads the host clock's offset from UTC off it.
"""

from __future__ import annotations

import math
from typing import Any

from .common import Ctx, StandardMapping, no_channel

NAV_SAT_FIX = "sensor_msgs/msg/NavSatFix"
TIME_REFERENCE = "sensor_msgs/msg/TimeReference"
#: GGA fix quality -> NavSatStatus.status (-1 no fix, 0 fix, 1 SBAS/differential, 2 GBAS/RTK)
_FIX_STATUS = {0: -1, 1: 0, 2: 1, 3: 0, 4: 2, 5: 2, 6: 0, 7: 0, 8: 0}
#: a GPS receiver's user equivalent range error (m), for a covariance from the HDOP
UERE_M = 5.0
PPS_CHANNELS = 10


def build(c: Ctx) -> list[StandardMapping]:
    if c.t.chan_count < 6:
        raise ValueError(
            f"{c.board}/{c.t.name}: NavSatFix wants the gps_nmea channel layout (6 or more)"
        )
    out = [StandardMapping(NAV_SAT_FIX, "fix", no_channel, _fix(c), frame=c.frame)]
    if c.t.chan_count >= PPS_CHANNELS:
        out.append(
            StandardMapping(TIME_REFERENCE, "time_reference", no_channel, _pps(c), frame=c.frame)
        )
    return out


def _fix(c: Ctx) -> Any:
    import numpy as np

    Fix, Status = c.T(NAV_SAT_FIX), c.T("sensor_msgs/msg/NavSatStatus")

    def build_fix(host_ns: list[int], values: list[Any]) -> bytes:
        lat, lon, alt, quality, _sats, hdop = values[:6]
        fixed = lat is not None and lon is not None and quality
        status = _FIX_STATUS.get(int(quality or 0), 0) if fixed else -1
        cov = np.zeros(9, dtype=np.float64)
        cov_type = 0  # COVARIANCE_TYPE_UNKNOWN
        if hdop is not None:
            h = hdop / 100 * UERE_M
            cov[0] = cov[4] = h * h
            cov[8] = (2 * h) ** 2  # vertical: about twice the horizontal
            cov_type = 1  # COVARIANCE_TYPE_APPROXIMATED
        msg = Fix(
            header=c.header(max(host_ns)),
            status=Status(status=status, service=1),  # SERVICE_GPS
            latitude=lat * 1e-7 if fixed else math.nan,
            longitude=lon * 1e-7 if fixed else math.nan,
            altitude=alt / 1000 if fixed and alt is not None else math.nan,
            position_covariance=cov,
            position_covariance_type=cov_type,
        )
        return c.cdr(msg, NAV_SAT_FIX)

    return build_fix


def _pps(c: Ctx) -> Any:
    Ref, Time = c.T(TIME_REFERENCE), c.T("builtin_interfaces/msg/Time")

    def build_ref(host_ns: list[int], values: list[Any]) -> bytes | None:
        day, ms = values[8], values[9]
        if day is None or ms is None or not host_ns[9]:
            return None  # not stamped at a PPS edge
        if not 0 <= ms < 86_400_000 or day < 0:
            raise ValueError(f"UTC day {day}, {ms} ms is no time")
        sec, msec = divmod(day * 86_400_000 + ms, 1000)
        ref = Time(sec=sec, nanosec=msec * 1_000_000)
        msg = Ref(header=c.header(host_ns[9]), time_ref=ref, source="gps")
        return c.cdr(msg, TIME_REFERENCE)

    return build_ref
