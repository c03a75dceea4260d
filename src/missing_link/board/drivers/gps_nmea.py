# A GPS receiver speaking NMEA 0183 on a UART (`uart`, `tx`, `rx`, `baud`), optionally with its
# PPS output on `pps_pin`.
#
# Sentences are "$<talker><type>,<fields>*<hh>\r\n" with hh the XOR of the characters between
# '$' and '*' in hex; a sentence whose checksum is missing or wrong is counted
# (`checksum_errors`) and dropped, as is one longer than NMEA's 82 characters.  Two are used,
# from any talker (GP, GN, GL, GA, BD):
#   GGA  time, latitude, N/S, longitude, E/W, fix quality (0 none, 1 GPS, 2 DGPS, 4 RTK fixed,
#        5 RTK float, 6 dead reckoning...), satellites used, HDOP, altitude above mean sea level
#   RMC  time, status (A valid, V void), latitude, longitude, speed over ground (knots), course
#        over ground (degrees true), date (ddmmyy: years 80-99 are 1980-1999, the rest 20yy)
# A sample goes out with each GGA, with the speed and course of the RMC of the same second when
# one came (else N/A).  Without a fix (quality 0) position and altitude are N/A.
#
# Channels (int32, so a position keeps its centimetres: a float32 would not):
#   0 latitude, 1 longitude (1e-7 degree, north and east positive), 2 altitude (mm above MSL),
#   3 fix quality, 4 satellites, 5 HDOP (x 100), 6 speed (mm/s), 7 course (0.01 degree),
#   8 UTC day (days since 1970-01-01), 9 UTC time of day (ms) of the PPS edge the sample is
#   stamped at: only on the fix of a whole second stamped at its PPS edge, with a valid RMC's
#   date (the RMC of that second, or of the second before: receivers that send GGA first);
#   N/A otherwise (no PPS, a 5/10 Hz receiver's fixes between the edges, no valid date, a leap
#   second: POSIX time has none).  A host that reads the first 8 channels reads what it read.
# The host publishes them as sensor_msgs/msg/NavSatFix, and channels 8 and 9 as
# sensor_msgs/msg/TimeReference (ros/standard/gnss.py): UTC against the board's clock.
#
# Stamps: when the sentence's '$' was read (the receiver sends a fix some 100-500 ms after the
# second it belongs to: that is what the stamp then says).  With `pps_pin` the fix is stamped at
# the PPS edge that began its second (the receiver's pulse marks the top of each UTC second, and
# the sentences of that second follow it), plus the sentence time's fraction of a second (5 or
# 10 Hz receivers); an edge older than 1.1 s is not used.
#
# A dropped sentence is a fault in the board's log (board/log.py, "bad checksum"): the first
# said, every one counted.

from ..log import CHECKSUM, report
from . import Driver

NA = -2147483648
MAX_SENTENCE = 82
PPS_VALID_US = 1100000


def nmea_checksum(body):
    c = 0
    for ch in body:
        c ^= ch
    return c


def _coord(text, hemi, degree_digits):
    # ddmm.mmmm / dddmm.mmmm -> 1e-7 degree (integer maths: no float32 rounding)
    if not text or "." not in text:
        return None
    whole, frac = text.split(".")
    deg = int(whole[:degree_digits])
    minutes = int(whole[degree_digits:] + (frac + "00000")[:5])  # minutes * 1e5
    e7 = deg * 10000000 + minutes * 100 // 60  # (minutes * 1e5 / 60) * 100 = 1e-7 degree
    return -e7 if hemi in ("S", "W") else e7


def _decimal(text, scale):
    # "12.34" -> round(12.34 * scale) without floats
    if not text:
        return None
    neg = text.startswith("-")
    if neg:
        text = text[1:]
    whole, _, frac = text.partition(".")
    digits = 0
    s = scale
    while s > 1:
        s //= 10
        digits += 1
    frac = (frac + "0" * (digits + 1))[: digits + 1]
    v = (int(whole or "0") * scale * 10 + int(frac) + 5) // 10
    return -v if neg else v


def _seconds_fraction_us(hhmmss):
    _, _, frac = hhmmss.partition(".")
    return int((frac + "000000")[:6]) if frac else 0


def _time_of_day_ms(hhmmss):
    # "hhmmss[.sss]" -> ms since midnight; None when empty or beyond the day (a leap second)
    whole = hhmmss.partition(".")[0]
    if len(whole) != 6:
        return None
    h, m, s = int(whole[:2]), int(whole[2:4]), int(whole[4:])
    if h > 23 or m > 59 or s > 59:
        return None
    return ((h * 60 + m) * 60 + s) * 1000 + _seconds_fraction_us(hhmmss) // 1000


def days_since_1970(y, m, d):
    # the civil date's day number (1970-01-01 is 0), for the Gregorian calendar, integer maths
    # (the days before each March, so February's leap day is the year's last)
    y -= 1 if m <= 2 else 0
    era = y // 400
    yoe = y - era * 400
    doy = (153 * (m + (-3 if m > 2 else 9)) + 2) // 5 + d - 1
    return era * 146097 + yoe * 365 + yoe // 4 - yoe // 100 + doy - 719468


def _date_days(ddmmyy):
    # RMC's date -> days since 1970-01-01; None when empty or not a date
    if len(ddmmyy) != 6:
        return None
    d, m, y = int(ddmmyy[:2]), int(ddmmyy[2:4]), int(ddmmyy[4:])
    if not (1 <= m <= 12 and 1 <= d <= 31):
        return None
    return days_since_1970(y + (1900 if y >= 80 else 2000), m, d)


class GpsNmea(Driver):
    PREFIX = "gps"
    MODEL = "NMEA 0183"
    CHANNELS = 10
    DTYPE = "int32_t"
    NA = NA
    OPTIONS = {"kind": "sensor", "ros": "sensor_msgs/msg/NavSatFix"}
    CONFIG = ()

    def __init__(self, machine, clock, uart, tx=None, rx=None, baud=9600, pps_pin=None):
        self.clock = clock
        kw = {"baudrate": baud, "rxbuf": 1024}
        if tx is not None:
            kw["tx"] = machine.Pin(tx)
        if rx is not None:
            kw["rx"] = machine.Pin(rx)
        self._uart = machine.UART(uart, **kw)
        self._line = bytearray()
        self._line_us = None  # when the current sentence's '$' was read
        self._rmc = None  # (time, speed mm/s, course 0.01 deg) of the last RMC
        self._date = None  # (UTC day, ms of day) of the last valid RMC with a date
        self._pps = None  # clock at the newest PPS edge
        if pps_pin is not None:
            self._pps_pin = machine.Pin(pps_pin, machine.Pin.IN)
            self._pps_pin.irq(self._on_pps, machine.Pin.IRQ_RISING)
        self.sentences = 0
        self.checksum_errors = 0
        self.fixes = 0
        self.pps_edges = 0
        self._due = None

    def _on_pps(self, _pin):
        self._pps = self.clock()
        self.pps_edges += 1

    def next_due_us(self):
        return self._due

    def poll(self, now):
        self._due = now + 10000  # ~10 bytes at 9600 baud between looks
        if not self._uart.any():
            return
        data = self._uart.read()
        if not data:
            return
        for b in data:
            if b == 0x24:  # '$': a sentence starts (anything before it was noise or a cut one)
                self._line = bytearray(b"$")
                self._line_us = now
            elif self._line_us is None:
                continue
            elif b == 0x0A:  # '\n'
                self._sentence(bytes(self._line).rstrip(b"\r"), self._line_us)
                self._line = bytearray()
                self._line_us = None
            else:
                self._line.append(b)
                if len(self._line) > MAX_SENTENCE:
                    self._bad("a sentence over %d characters (not NMEA)" % MAX_SENTENCE)
                    self._line = bytearray()
                    self._line_us = None

    def _sentence(self, line, at_us):
        star = line.find(b"*")
        if star < 0 or len(line) != star + 3:
            self._bad("a sentence without its checksum")
            return
        body = line[1:star]
        try:
            want = int(line[star + 1 :].decode(), 16)
            text = body.decode()
        except (ValueError, UnicodeError):
            self._bad("a sentence that is not text")
            return
        if nmea_checksum(body) != want:
            self._bad("a sentence whose checksum is wrong")
            return
        self.sentences += 1
        f = text.split(",")
        kind = f[0][2:]
        try:
            if kind == "RMC" and len(f) >= 9:
                valid = f[2] == "A"
                speed = _decimal(f[7], 1000)  # knots * 1000
                self._rmc = (
                    f[1],
                    speed * 1852 // 3600 if valid and speed is not None else None,  # mm/s
                    _decimal(f[8], 100) if valid else None,
                )
                self._date = None  # (first: a bad date below leaves none, not the last one)
                if valid and len(f) > 9:  # (a short RMC: its speed and course still hold)
                    day, tod = _date_days(f[9]), _time_of_day_ms(f[1])
                    self._date = None if day is None or tod is None else (day, tod)
            elif kind == "GGA" and len(f) >= 10:
                self._gga(f, at_us)
        except (ValueError, IndexError):
            self._bad("a sentence with a valid checksum but bad fields")

    def _bad(self, what):
        # dropped and counted; the first said in the board's log (log.py: then only counted)
        self.checksum_errors += 1
        report(self, CHECKSUM, what)

    def _gga(self, f, at_us):
        quality = int(f[6] or "0")
        fixed = quality > 0
        values = [
            _coord(f[2], f[3], 2) if fixed else None,
            _coord(f[4], f[5], 3) if fixed else None,
            _decimal(f[9], 1000) if fixed else None,
            quality,
            int(f[7] or "0"),
            _decimal(f[8], 100),
            None,
            None,
        ]
        rmc = self._rmc
        if rmc is not None and rmc[0] == f[1]:
            values[6], values[7] = rmc[1], rmc[2]
        stamp = at_us
        pps = self._pps
        if pps is not None and 0 <= at_us - pps < PPS_VALID_US:
            stamp = pps + _seconds_fraction_us(f[1])
            if stamp == pps:  # the fix of the edge's own second: its UTC
                values += self._utc(f[1])
        self.fixes += 1 if fixed else 0
        for ch in range(self.CHANNELS):
            self.emit(ch, values[ch] if ch < len(values) else None, stamp)

    def _utc(self, hhmmss):
        # [UTC day, ms of day] of the GGA's time, the day from the last valid RMC's date: the
        # same second's, or the second before's (a day later when midnight came between);
        # [] when there is none that recent (a date is never carried further)
        date, tod = self._date, _time_of_day_ms(hhmmss)
        if date is None or tod is None:
            return []
        day, since = date[0], tod - date[1]
        if since < 0:  # (midnight between the RMC and this GGA)
            day, since = day + 1, since + 86400000
        if since > 1000:
            self._date = None
            return []
        return [day, tod]
