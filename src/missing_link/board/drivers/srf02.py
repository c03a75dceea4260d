# Devantech SRF02 ultrasonic ranger on I2C (default address 0xE0 in the datasheet's 8-bit form,
# 0x70 for machine.I2C).
#
# Registers: 0 = command (write) / software revision (read), 1 = unused (reads 0x80), 2-3 = range
# high/low byte, 4-5 = autotune minimum range.  Writing 0x50/0x51/0x52 to register 0 starts a
# ranging in inches/cm/µs; for up to 65 ms the SRF02 does not answer on the bus (reads NACK, or
# 0xFF on some masters), so we poll register 0 from 65 ms on and give up (N/A) at 100 ms.
# A range of 0 (no echo) or below the minimum range is N/A.  The sample is stamped when the echo
# reflected: the ping's start plus half the echo's flight (µs mode gives it directly; in cm it is
# range * 58.3 µs).  The address is changed with the sequence 0xA0, 0xAA, 0xA5, new address
# written to register 0 in four transactions (change_address).

from ..log import TIMEOUT, bus_fault, report
from . import Ranger, ranger_options

CMD_INCH = 0x50
CMD_CM = 0x51
CMD_US = 0x52
RANGING_US = 65000
GIVE_UP_US = 100000
CHECK_US = 5000
US_PER_CM = 58.3  # round trip of sound at 343 m/s over 1 cm


class SRF02(Ranger):
    PREFIX = "srf02"
    MODEL = "SRF02"
    OPTIONS = ranger_options("cm")
    # The SRF02 has no range or gain registers (the SRF08 has): what can change at run time is
    # how often it pings (a ranging takes 65 ms) and the shortest range it reports.
    CONFIG = (
        ("rate_hz", "float", (0.1, 15.38), False),
        ("min_range", "int", (0, 600), False),
        ("units", "enum", ("cm", "us", "inch"), True),
    )
    PLAIN = ("min_range", "units")  # (units: read only)

    def __init__(self, machine, clock, i2c, address=0x70, rate_hz=10, units="cm", min_range=16):
        Ranger.__init__(self, clock, min(rate_hz, 1000000 / RANGING_US))
        self._i2c = i2c
        self.address = address
        if units not in ("cm", "us", "inch"):
            raise ValueError("srf02 units: cm, us or inch")
        self.units = units
        self._cmd = {"cm": CMD_CM, "us": CMD_US, "inch": CMD_INCH}[units]
        self.min_range = min_range
        self._ping_us = None  # when the running ranging started
        self._check_us = None
        self.timeouts = 0
        self.bus_errors = 0

    def next_due_us(self):
        return self._check_us if self._ping_us is not None else self._due

    def poll(self, now, fresh=False):
        if self._ping_us is None:
            Ranger.poll(self, now, fresh)
            return
        if now < self._check_us:
            return
        if self._ready():
            self._finish(now)
        elif now - self._ping_us >= GIVE_UP_US:
            self.timeouts += 1
            report(
                self,
                TIMEOUT,
                "no range within %d ms at 0x%02x" % (GIVE_UP_US // 1000, self.address),
            )
            self._ping_us = None
            self.emit(0, None, now)
        else:
            self._check_us = now + CHECK_US

    def measure(self, now):
        try:
            self._i2c.writeto_mem(self.address, 0, bytes((self._cmd,)))
        except OSError as e:
            bus_fault(self, e, True)  # (between rangings it answers: absent, else)
            self.bus_errors += 1
            self.emit(0, None, now)
            return
        self._ping_us = self.clock()
        self._check_us = self._ping_us + RANGING_US

    def _ready(self):
        try:
            return self._i2c.readfrom_mem(self.address, 0, 1)[0] != 0xFF
        except OSError:
            return False  # busy ranging: the SRF02 does not acknowledge

    def _finish(self, now):
        ping = self._ping_us
        self._ping_us = None
        try:
            hi, lo = self._i2c.readfrom_mem(self.address, 2, 2)
        except OSError as e:
            bus_fault(self, e, False)
            self.bus_errors += 1
            self.emit(0, None, now)
            return
        value = (hi << 8) | lo
        if self.units == "us":
            flight, too_close = value, value < self.min_range * US_PER_CM
        elif self.units == "cm":
            flight, too_close = value * US_PER_CM, value < self.min_range
        else:
            flight, too_close = value * 2.54 * US_PER_CM, value * 2.54 < self.min_range
        if value == 0 or too_close:
            self.emit(0, None, now)
        else:
            self.emit(0, value, ping + int(flight / 2))

    def change_address(self, new_address):
        # 7-bit address (0x70..0x7F); the datasheet lists 8-bit 0xE0..0xFE.
        if not 0x70 <= new_address <= 0x7F:
            raise ValueError("SRF02 addresses are 0x70..0x7F (8-bit 0xE0..0xFE)")
        # A ranging in flight: the SRF02 acknowledges nothing until it ends (the sequence
        # failed with EIO); its range first, or its give-up, as the loop would (bounded: 100 ms)
        while self._ping_us is not None:
            self._check_us = 0
            self.poll(self.clock())
        for b in (0xA0, 0xAA, 0xA5, new_address << 1):
            self._i2c.writeto_mem(self.address, 0, bytes((b,)))
        self.address = new_address
