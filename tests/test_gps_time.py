"""A GPS's UTC for each PPS edge (issue 35.2: sensor_msgs/msg/TimeReference): the gps_nmea
driver (board/drivers/gps_nmea.py) reports channel 8 = the UTC day and 9 = the UTC ms of day of
the PPS edge a whole second's fix is stamped at, from RMC's date and the sentences' time, N/A
otherwise; the simulated receiver (virtual/world/devices.py) sends RMC with its date, turning at
midnight.  The driver runs on CPython here against a UART and a pin of its own; under
MicroPython and on AVR it is tested end to end (tests/test_rover.py, test_gps_time_ros2.py,
test_avr_rover.py)."""

from __future__ import annotations

import datetime
from collections.abc import Callable
from typing import Any

import pytest

from missing_link.board.drivers.gps_nmea import GpsNmea, days_since_1970, nmea_checksum
from missing_link.virtual.world import machine as world
from missing_link.virtual.world.devices import GpsReceiver, civil_date

NA = None
MUNICH = "4807.0380,N,01131.0000,E"


class Uart:
    def __init__(self) -> None:
        self.rx = bytearray()

    def any(self) -> int:
        return len(self.rx)

    def read(self) -> bytes:
        data, self.rx = bytes(self.rx), bytearray()
        return data


class Pin:
    IN, IRQ_RISING = 0, 1

    def __init__(self, n: int, mode: int | None = None) -> None:
        self.handler: Callable[[Any], None] | None = None

    def irq(self, handler: Callable[[Any], None], trigger: int) -> None:
        self.handler = handler


class Machine:
    """The two parts of `machine` the driver uses: its UART and its PPS pin (``pins``)."""

    def __init__(self) -> None:
        self.uart = Uart()
        self.pins: list[Pin] = []
        made = self.pins

        class MadePin(Pin):
            def __init__(self, n: int, mode: int | None = None) -> None:
                super().__init__(n, mode)
                made.append(self)

        self.Pin = MadePin

    def UART(self, n: int, **kw: Any) -> Uart:
        return self.uart


class Gps:
    """The driver on a fake UART and PPS pin, its board clock set by the test; ``samples``:
    (channel, value, stamp) of each callback."""

    def __init__(self, pps: bool = True) -> None:
        self.now = 1_000_000
        self.m = Machine()
        self.driver = GpsNmea(self.m, lambda: self.now, 1, pps_pin=10 if pps else None)
        self.samples: list[tuple[int, Any, int]] = []
        self.driver.set_cb(lambda ch, v, t: self.samples.append((ch, v, t)))

    def edge(self, at: int) -> None:
        self.now = at
        handler = self.m.pins[0].handler
        assert handler is not None
        handler(None)

    def send(self, at: int, *bodies: str) -> list[tuple[int, Any, int]]:
        """Sentences read at board time ``at``: the channels of the sample they made (if any)."""
        for body in bodies:
            self.m.uart.rx += b"$%s*%02X\r\n" % (body.encode(), nmea_checksum(body.encode()))
        self.now = at
        self.samples = []
        self.driver.poll(at)
        return self.samples


def rmc(hms: str, date: str, status: str = "A") -> str:
    return f"GPRMC,{hms},{status},{MUNICH},022.4,084.4,{date},003.1,W"


def gga(hms: str) -> str:
    return f"GPGGA,{hms},{MUNICH},1,08,0.9,545.4,M,46.9,M,,"


def utc_of(s: list[tuple[int, Any, int]]) -> tuple[Any, Any]:
    return s[8][1], s[9][1]


def test_days_since_1970_is_the_calendars() -> None:
    for day in range(-800, 60000, 13):
        d = datetime.date(1970, 1, 1) + datetime.timedelta(days=day)
        assert days_since_1970(d.year, d.month, d.day) == day
        assert civil_date(day) == (d.year, d.month, d.day)  # (the world's inverse too)


def test_the_fix_of_a_pps_edge_carries_that_edges_utc() -> None:
    g = Gps()
    g.edge(5_000_000)
    s = g.send(5_150_000, rmc("123519.00", "230394"), gga("123519.00"))
    assert [ch for ch, _v, _t in s] == list(range(10))
    assert {t for _ch, _v, t in s} == {5_000_000}  # every channel at the edge
    assert utc_of(s) == (8847, (12 * 3600 + 35 * 60 + 19) * 1000)  # 23 March 1994 12:35:19
    assert [v for _ch, v, _t in s[:8]] == [481173000, 115166666, 545400, 1, 8, 90, 11523, 8440]
    # a receiver that sends GGA first (some MediaTek): the date of the RMC of the second before
    g.edge(6_000_000)
    s = g.send(6_080_000, gga("123520.00"))
    assert utc_of(s) == (8847, (12 * 3600 + 35 * 60 + 20) * 1000)
    s = g.send(6_150_000, rmc("123520.00", "230394"))
    assert s == []  # (an RMC alone makes no sample)


def test_midnight_turns_the_day_whichever_sentence_comes_first() -> None:
    g = Gps()
    g.edge(1_000_000)
    assert utc_of(g.send(1_100_000, rmc("235959.00", "311299"), gga("235959.00"))) == (
        10956,  # 31 December 1999
        86_399_000,
    )
    g.edge(2_000_000)  # GGA of the new day before its RMC: the day after the RMC's
    assert utc_of(g.send(2_080_000, gga("000000.00"))) == (10957, 0)
    g.edge(3_000_000)
    assert utc_of(g.send(3_100_000, rmc("000001.00", "010100"), gga("000001.00"))) == (10957, 1000)


@pytest.mark.parametrize(
    ("case", "sentences"),
    [
        ("no valid fix", [rmc("123519.00", "230394", "V"), gga("123519.00")]),
        ("no date", [rmc("123519.00", ""), gga("123519.00")]),
        ("between two edges (5 Hz)", [rmc("123519.20", "230394"), gga("123519.20")]),
        ("a leap second", [rmc("235960.00", "301216"), gga("235960.00")]),
        ("an RMC 2 s old", [rmc("123517.00", "230394"), gga("123519.00")]),
        ("a date that is none", [rmc("123519.00", "2303x4"), gga("123519.00")]),
        ("an RMC without a date", [rmc("123519.00", "").rsplit(",", 3)[0], gga("123519.00")]),
    ],
)
def test_utc_is_na_off_a_whole_seconds_pps_edge(case: str, sentences: list[str]) -> None:
    g = Gps()
    g.edge(1_000_000)
    s = g.send(1_150_000, *sentences)
    assert len(s) == 10 and utc_of(s) == (NA, NA), case
    assert s[3][1] == 1  # (the fix itself is there)


def test_a_bad_date_is_counted_and_forgets_the_last_good_one() -> None:
    g = Gps()
    g.edge(1_000_000)
    g.send(1_100_000, rmc("123519.00", "230394"), gga("123519.00"))
    g.edge(2_000_000)  # (the GGA first would take the date of the RMC before: not now)
    s = g.send(2_100_000, rmc("123520.00", "2303x4"), gga("123520.00"))
    assert utc_of(s) == (NA, NA) and g.driver.checksum_errors == 1
    short = rmc("123521.00", "230394").rsplit(",", 3)[0]  # (ends at the course: no date)
    g.edge(3_000_000)
    s = g.send(3_100_000, short, gga("123521.00"))
    assert utc_of(s) == (NA, NA) and g.driver.checksum_errors == 1  # (not a bad sentence)
    assert s[6][1] == 11523  # (its speed still holds)


def test_without_pps_no_utc_and_a_stale_date_is_not_kept() -> None:
    g = Gps(pps=False)
    s = g.send(1_150_000, rmc("123519.00", "230394"), gga("123519.00"))
    assert utc_of(s) == (NA, NA) and {t for _c, _v, t in s} == {1_150_000}  # at the '$'
    g = Gps()
    g.edge(1_000_000)
    g.send(1_100_000, rmc("123519.00", "230394"), gga("123519.00"))
    g.edge(3_000_000)  # no RMC for two seconds: the date is not carried on
    assert utc_of(g.send(3_080_000, gga("123521.00"))) == (NA, NA)
    g.edge(4_000_000)
    assert utc_of(g.send(4_080_000, gga("123522.00"))) == (NA, NA)  # (forgotten, not found again)


def test_the_simulated_receivers_rmc_has_its_date_turning_at_midnight() -> None:
    uart = 97  # (a UART of its own in the process's world, taken back after)
    rx = GpsReceiver(uart)
    try:
        rx.utc0 = 946684799  # 1999-12-31 23:59:59
        text = rx._sentences(rx.utc0).decode() + rx._sentences(rx.utc0 + 1).decode()
    finally:
        world.WORLD.uart_sources.pop(uart, None)
    rmcs = [line.split(",") for line in text.split() if line.startswith("$GPRMC")]
    assert [(f[1], f[9]) for f in rmcs] == [("235959.00", "311299"), ("000000.00", "010100")]


@pytest.mark.micropython
@pytest.mark.slow
def test_the_simulated_receiver_counts_seconds_across_a_long_gap() -> None:
    """Unread (or off) for longer than ticks_diff spans (537 s), the receiver measured its gap in
    wrapped µs: OverflowError out of the driver's poll near 537 s, 474 s back at 600 s, 26 s
    counted for 1100 s.  Real MicroPython, under simulated time as --fast runs it."""
    from .helpers import simworld_probe

    gaps_ms = [1000, 536_900, 600_000, 1_100_000, 7_200_000, 1000]
    got = simworld_probe("gps_gap", [[g] for g in gaps_ms])
    assert [g["got"] for g in got] == [["=", (2500 + g + 1) // 1000 - 2] for g in gaps_ms]
