# Three-axis magnetometers on I2C, published in tesla (sensor_msgs/msg/MagneticField on the host).
#
# Honeywell HMC5883L (datasheet rev E, address 0x1E): identification registers 10-12 read "H43".
# Configuration A (0) = 8-sample averaging | output rate | normal measurement; B (1) = gain
# (bits 7-5: 1370, 1090, 820, 660, 440, 390, 330, 230 LSB/gauss for 0.88 ... 8.1 Ga); Mode (2) =
# 0, continuous.  Data: six bytes from 3, X Z Y (not X Y Z), big-endian int16; -4096 on an axis
# means it overflowed (N/A).  After a gain change the next reading still has the old gain (the
# datasheet says so): it is skipped.
#
# QST QMC5883L (datasheet 1.0, address 0x0D), sold on the same breakout boards: chip id 0x0D
# reads 0xFF; control 1 (9) = oversampling 512 | range (2 G: 12000 LSB/G, 8 G: 3000) | output
# rate (10, 50, 100, 200 Hz) | continuous; SET/RESET period (0x0B) = 1 as the datasheet asks;
# soft reset in control 2 (0x0A) bit 7.  Status (6): bit 0 data ready, bit 1 overflow (N/A).
# Data: six bytes from 0, X Y Z, little-endian int16.
#
# A bus error gives N/A on all three axes and the chip is set up again before the next sample.
# 1 gauss = 1e-4 tesla.

import struct

from ..log import WrongPart, bus_fault
from . import Periodic

HMC_GAINS = (1370, 1090, 820, 660, 440, 390, 330, 230)  # LSB per gauss
HMC_RANGES = (0.88, 1.3, 1.9, 2.5, 4.0, 4.7, 5.6, 8.1)  # +- gauss
HMC_RATES = (0.75, 1.5, 3.0, 7.5, 15.0, 30.0, 75.0)  # Hz, output rate bits 4-2
QMC_RANGES = (2, 8)
QMC_LSB = (12000, 3000)
QMC_RATES = (10, 50, 100, 200)
GAUSS = 1e-4


class _Compass(Periodic):
    # A chip's RANGES (+- gauss: the range_gauss key's choices) and its LSB per gauss at each
    PREFIX = "compass"
    CHANNELS = 3
    DTYPE = "float"
    NA = float("nan")
    OPTIONS = {"unit": "T", "kind": "sensor", "ros": "sensor_msgs/msg/MagneticField"}

    def __init__(self, clock, i2c, address, rate_hz, range_gauss):
        if range_gauss not in self.RANGES:
            raise ValueError("%s: range_gauss in %s" % (self.MODEL.lower(), self.RANGES))
        Periodic.__init__(self, clock, rate_hz)
        self._i2c = i2c
        self.address = address
        self._range = self.RANGES.index(range_gauss)
        self._ok = False
        self.bus_errors = 0
        self.overflows = 0

    def get_config(self, key):
        if key == "range_gauss":
            return self.RANGES[self._range]
        return Periodic.get_config(self, key)

    def set_config(self, key, value):
        if key == "range_gauss":
            self._range = self.RANGES.index(value)
        else:
            Periodic.set_config(self, key, value)
        self._ok = False  # the chip gets the new range, or the output rate that follows ours

    def _tesla_per_lsb(self):
        return GAUSS / self.LSB[self._range]

    def _rate_code(self, rates):
        # the slowest of the chip's output rates at least as fast as ours (else its fastest)
        rate = 1000000 / self.period_us
        for i, r in enumerate(rates):
            if r >= rate:
                return i
        return len(rates) - 1

    def _na(self, now):
        for ch in range(3):
            self.emit(ch, None, now)

    def measure(self, now):
        starting = not self._ok
        try:
            if not self._ok:
                self.init()
                self._ok = True
            stamp = self.clock()
            xyz = self.read()
        except OSError as e:
            bus_fault(self, e, starting)  # (log.py: said once, then counted)
            self.bus_errors += 1
            self._ok = False
            self._na(now)
            return
        if xyz is None:  # a reading to throw away (HMC5883L after a gain change)
            return
        for ch in range(3):
            v = xyz[ch]
            if v is None:
                self.overflows += 1
            self.emit(ch, None if v is None else v * self._tesla_per_lsb(), stamp)


class HMC5883L(_Compass):
    MODEL = "HMC5883L"
    RANGES = HMC_RANGES
    LSB = HMC_GAINS
    CONFIG = (
        ("rate_hz", "float", (0.1, 75.0), False),
        ("range_gauss", "enum", HMC_RANGES, False),
    )

    def __init__(self, machine, clock, i2c, address=0x1E, rate_hz=15, range_gauss=1.3):
        _Compass.__init__(self, clock, i2c, address, rate_hz, range_gauss)
        self._skip = 0

    def init(self):
        i2c, a = self._i2c, self.address
        ident = bytes(i2c.readfrom_mem(a, 10, 3))
        if ident != b"H43":
            raise WrongPart("identification %r, not an HMC5883L (b'H43')" % ident)
        do = self._rate_code(HMC_RATES)
        i2c.writeto_mem(a, 0, bytes(((3 << 5) | (do << 2),)))  # 8-sample average, rate, normal
        i2c.writeto_mem(a, 1, bytes((self._range << 5,)))
        i2c.writeto_mem(a, 2, b"\x00")  # continuous
        self._skip = 1  # the first reading after a gain change has the old gain

    def read(self):
        x, z, y = struct.unpack(">hhh", self._i2c.readfrom_mem(self.address, 3, 6))
        if self._skip:
            self._skip -= 1
            return None
        return tuple(None if v == -4096 else v for v in (x, y, z))


class QMC5883L(_Compass):
    MODEL = "QMC5883L"
    RANGES = QMC_RANGES
    LSB = QMC_LSB
    CONFIG = (
        ("rate_hz", "float", (0.1, 200.0), False),
        ("range_gauss", "enum", QMC_RANGES, False),
    )

    def __init__(self, machine, clock, i2c, address=0x0D, rate_hz=50, range_gauss=8):
        _Compass.__init__(self, clock, i2c, address, rate_hz, range_gauss)

    def init(self):
        i2c, a = self._i2c, self.address
        chip = i2c.readfrom_mem(a, 0x0D, 1)[0]
        if chip != 0xFF:
            raise WrongPart("chip id 0x%02x, not a QMC5883L (0xff)" % chip)
        i2c.writeto_mem(a, 0x0A, b"\x80")  # soft reset
        i2c.writeto_mem(a, 0x0B, b"\x01")  # SET/RESET period, as the datasheet asks
        odr = self._rate_code(QMC_RATES)
        i2c.writeto_mem(a, 0x09, bytes(((self._range << 4) | (odr << 2) | 0x01,)))  # OSR 512

    def read(self):
        status = self._i2c.readfrom_mem(self.address, 6, 1)[0]
        x, y, z = struct.unpack("<hhh", self._i2c.readfrom_mem(self.address, 0, 6))
        if status & 0x02:  # overflow: every axis is suspect
            return (None, None, None)
        return (x, y, z)
