"""The simulated devices on a UART (devices.py says how the models are made): a GPS receiver
speaking NMEA 0183 at its baud rate, with its PPS pulse, at WORLD.uart_sources[id].  The
MicroPython subset only.
"""

from .machine import WORLD, ticks_add, ticks_diff, ticks_ms, ticks_us
from .units import degrees, scaled


def _now_us():
    return ticks_us()


def _nmea(body, bad):
    c = 0
    for ch in body.encode():
        c ^= ch
    if bad:
        c ^= 0x5A
    return "$%s*%02X\r\n" % (body, c)


def civil_date(days):
    # days since 1970-01-01 -> (year, month, day), Gregorian (not the driver's maths: its inverse)
    z = days + 719468
    era = z // 146097
    doe = z - era * 146097
    yoe = (doe - doe // 1460 + doe // 36524 - doe // 146096) // 365
    doy = doe - (365 * yoe + yoe // 4 - yoe // 100)
    mp = (5 * doy + 2) // 153
    d = doy - (153 * mp + 2) // 5 + 1
    m = mp + 3 if mp < 10 else mp - 9
    return yoe + era * 400 + (1 if m <= 2 else 0), m, d


def _tenths(v, width):
    # an integer of tenths as NMEA writes it: "%0{width}.1f" (width 0: as short as it goes)
    sign, v = ("-" if v < 0 else ""), abs(v)
    text = "%d.%d" % (v // 10, v % 10)
    return sign + "0" * (width - len(text) - len(sign)) + text


NMEA_EXAMPLE_UTC = 764426119  # 1994-03-23 12:35:19 UTC (NMEA's own example), s since 1970


class GpsReceiver:
    # A GPS receiver's NMEA 0183 output on a UART: each second RMC then GGA (talker GP; latitude
    # ddmm.mmmm, longitude dddmm.mmmm, speed in knots, course in degrees true, altitude in m;
    # RMC's date ddmmyy), sent at `baud` (10 bits a byte): the bytes reach the UART as the line
    # carries them, when the firmware looks.  With a PPS pin, a rising edge at the top of each
    # second, before that second's sentences, as u-blox receivers send it (the pulse's width is
    # not modelled).  Every `bad_every`-th sentence has a wrong checksum (0: none).  Seconds
    # count from when the receiver was made; UTC starts at `utc0` (seconds since 1970: 12:35:19
    # on 23 March 1994, NMEA's own example; a test may move it, to midnight say) and the date
    # turns at midnight.  `edges`: (ticks_us, UTC second) of the newest PPS edges (at most 20).
    def __init__(self, uart, pps_pin=None, baud=9600):
        self.uart = uart
        self.pps_pin = pps_pin
        self.baud = baud
        # (in small integers, as the world sets them: worldfeed.py; lat, lon ... are properties)
        self.lat_deg, self.lat_e7 = 48, 1173000  # whole degrees and 1e-7, of one sign
        self.lon_deg, self.lon_e7 = 11, 5166670
        self.alt_dm, self.hdop_d = 5454, 9  # 0.1 m, 0.1
        self.quality, self.sats = 1, 8
        self.speed_dkn, self.course_dd = 224, 844  # 0.1 knot, 0.1 degree
        self.bad_every = 0
        self.sent = 0
        self.utc0 = NMEA_EXAMPLE_UTC
        self.pps_at = []  # ticks_us of the PPS edges (newest last, at most 20)
        self.edges = []  # (ticks_us, UTC second) of the same edges
        self._mark, self._base = _now_us(), 0  # a whole second since it was made, and which
        self._mark_ms = ticks_ms()  # ... in ms (ticks_ms spans 6.2 days, ticks_us 537 s)
        self._sec = -1
        self._out = b""  # this second's sentences
        self._out_t0 = 0
        self._fed = 0
        WORLD.uart_sources[uart] = self

    def _coord(self, deg, e7, width):
        # dd(d)mm.mmmm from whole degrees and 1e-7 degree, in integers
        d, m4 = abs(deg), (abs(e7) * 6 + 50) // 100  # (1e-4 minute)
        if m4 >= 600000:
            d, m4 = d + 1, m4 - 600000
        return ("%02d" if width == 2 else "%03d") % d + "%02d.%04d" % (m4 // 10000, m4 % 10000)

    lat = degrees("lat_deg", "lat_e7")
    lon = degrees("lon_deg", "lon_e7")
    alt = scaled("alt_dm", 10)  # m
    speed_kn = scaled("speed_dkn", 10)
    course = scaled("course_dd", 10)  # degrees
    hdop = scaled("hdop_d", 10)

    def _skip(self, k):
        # the mark moves on by k whole seconds, in both clocks
        self._mark = ticks_add(self._mark, k * 1000000)
        self._mark_ms = ticks_add(self._mark_ms, k * 1000)
        self._base += k

    def _sentences(self, utc):
        t, (y, mo, d) = utc % 86400, civil_date(utc // 86400)
        hms = "%02d%02d%02d.00" % (t // 3600, (t // 60) % 60, t % 60)
        date = "%02d%02d%02d" % (d, mo, y % 100)
        south, west = self.lat_deg < 0 or self.lat_e7 < 0, self.lon_deg < 0 or self.lon_e7 < 0
        ns, ew = ("S" if south else "N"), ("W" if west else "E")
        lat = self._coord(self.lat_deg, self.lat_e7, 2)
        lon = self._coord(self.lon_deg, self.lon_e7, 3)
        fixed = self.quality > 0
        rmc = "GPRMC,%s,%s,%s,%s,%s,%s,%s,%s,%s,003.1,W" % (
            hms, "A" if fixed else "V", lat if fixed else "", ns if fixed else "",
            lon if fixed else "", ew if fixed else "", _tenths(self.speed_dkn, 5),
            _tenths(self.course_dd, 5), date,
        )  # fmt: skip
        gga = "GPGGA,%s,%s,%s,%s,%s,%d,%02d,%s,%s,M,46.9,M,," % (
            hms, lat if fixed else "", ns if fixed else "", lon if fixed else "",
            ew if fixed else "", self.quality, self.sats, _tenths(self.hdop_d, 0),
            _tenths(self.alt_dm, 0) if fixed else "",
        )  # fmt: skip
        out = ""
        for body in (rmc, gga):
            self.sent += 1
            out += _nmea(body, self.bad_every and self.sent % self.bad_every == 0)
        return out.encode()

    def produce(self, now):
        # Whole seconds since the mark: unread (or off) longer than ticks_us spans (537 s), the
        # most of them counted in ms first, then the rest (under 2 s) in µs
        k = ticks_diff(ticks_ms(), self._mark_ms) // 1000 - 1
        while k > 0:  # (ticks_add takes under 2^29: steps of 500 s)
            step = k if k < 500 else 500
            self._skip(step)
            k -= step
        self._skip(ticks_diff(now, self._mark) // 1000000)
        if self._base > self._sec:
            self._sec = self._base
            utc = self.utc0 + self._sec
            if self.pps_pin is not None:
                self.pps_at.append(now)
                self.edges.append((now, utc))
                if len(self.pps_at) > 20:
                    self.pps_at.pop(0)
                    self.edges.pop(0)
                WORLD.set_level(self.pps_pin, 1)
                WORLD.set_level(self.pps_pin, 0)
            rest = self._out[self._fed :]  # (a slow reader: the line was still busy)
            self._out = rest + self._sentences(utc)
            self._out_t0, self._fed = now, 0
        due = ticks_diff(now, self._out_t0) * self.baud // 10000000 + 1
        if due > self._fed:
            chunk = self._out[self._fed : due]
            self._fed += len(chunk)
            uart = WORLD.uarts.get(self.uart)
            if uart is not None:
                uart.feed(chunk)
