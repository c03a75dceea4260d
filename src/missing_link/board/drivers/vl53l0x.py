# ST VL53L0X time-of-flight ranger on I2C (address 0x29).  ST documents the device through its
# API (UM2039) rather than a register map; the start-up below is the API's sequence reduced to
# what ranging with the default 33 ms timing budget needs:
#   * model id (0xC0) must read 0xEE;
#   * data init: I/O at 2.8 V (0x89 bit 0), I2C standard mode (0x88 = 0), and the "stop
#     variable" read from 0x91 behind the 0x80/0xFF/0x00 page sequence (it must be written back
#     before every ranging);
#   * the MSRC and pre-range signal-rate limit checks off (0x60 |= 0x12), the final-range
#     signal-rate limit 0.25 MCPS (0x44, Q9.7), all sequence steps (0x01 = 0xFF);
#   * interrupt on a new sample (0x0A = 0x04), active low (0x84 bit 4 clear), cleared (0x0B = 1);
#   * the reference calibrations: VHV (0x01 = 0x01, start 0x40|1) and phase (0x01 = 0x02,
#     start 1), each waited for on the interrupt status (0x13 & 7) and cleared; then the
#     sequence 0xE8 (DSS, pre-range, final range).
# Not done: ST's reference-SPAD selection and its table of tuning writes; without them the
# device ranges with its power-on SPAD map and tuning (a shorter reach, less accuracy).
#
# A ranging: single (`mode` single: written per sample, 0x00 = 1) or back-to-back (`mode`
# continuous: started once, 0x00 = 2); ready when 0x13 & 7 != 0; then the range status
# (0x14, bits 6-3; 11 = valid, anything else - no target, signal too weak, phase out of range -
# is N/A) and the range in mm (0x1E, big-endian), and the interrupt cleared.  Stamped in the
# middle of the timing budget (the ranging integrates over it).  A ranging not ready after 3
# budgets is a timeout (N/A) and the device is set up again.  Faults go to the board's log
# (board/log.py: each kind said once, then counted): not answering while it is set up (absent,
# unpowered), another part's model id, a calibration that never ends, a bus error, a timeout.

from ..log import TIMEOUT, NoReady, WrongPart, bus_fault, report
from . import Ranger, ranger_options

BUDGET_US = 33000
MODES = ("single", "continuous")


class VL53L0X(Ranger):
    PREFIX = "tof"
    MODEL = "VL53L0X"
    OPTIONS = ranger_options("mm", "30", "2000")
    CONFIG = (
        ("rate_hz", "float", (0.1, 30.0), False),  # a 33 ms budget
        ("mode", "enum", MODES, False),
    )

    def __init__(self, machine, clock, i2c, address=0x29, rate_hz=10, mode="single"):
        if mode not in MODES:
            raise ValueError("vl53l0x mode: single or continuous")
        Ranger.__init__(self, clock, min(rate_hz, 30.0))
        self._i2c = i2c
        self.address = address
        self.mode = mode
        self._ok = False
        self._stop = 0
        self._started = None  # when the running ranging started (board µs)
        self._running = False  # continuous mode started
        self._check = None  # single: when to look for the running ranging's result
        self.bus_errors = 0
        self.timeouts = 0

    def get_config(self, key):
        if key == "mode":
            return self.mode
        return Ranger.get_config(self, key)

    def set_config(self, key, value):
        if key == "mode":
            self.mode = value
            self._ok = False  # started again in the new mode
        else:
            Ranger.set_config(self, key, value)

    # ---- registers ----
    def _w(self, reg, value):
        self._i2c.writeto_mem(self.address, reg, bytes((value,)))

    def _r(self, reg):
        return self._i2c.readfrom_mem(self.address, reg, 1)[0]

    def _page(self, stop):
        # the sequence around the stop variable (0x91) the API writes before each ranging
        for reg, v in ((0x80, 1), (0xFF, 1), (0x00, 0)):
            self._w(reg, v)
        if stop is None:
            value = self._r(0x91)
        else:
            self._w(0x91, stop)
            value = stop
        for reg, v in ((0x00, 1), (0xFF, 0), (0x80, 0)):
            self._w(reg, v)
        return value

    def _wait_ready(self, budget_us):
        start = self.clock()
        while self._r(0x13) & 0x07 == 0:
            if self.clock() - start > budget_us:
                raise NoReady("no interrupt from its calibration")

    def init(self):
        model = self._r(0xC0)
        if model != 0xEE:
            raise WrongPart("model id 0x%02x, not a VL53L0X (0xee)" % model)
        self._w(0x89, self._r(0x89) | 0x01)  # 2.8 V I/O
        self._w(0x88, 0x00)  # standard I2C
        self._stop = self._page(None)
        self._w(0x60, self._r(0x60) | 0x12)  # MSRC and pre-range limit checks off
        self._i2c.writeto_mem(self.address, 0x44, bytes((0x00, 0x20)))  # 0.25 MCPS
        self._w(0x01, 0xFF)
        self._w(0x0A, 0x04)  # interrupt: new sample ready
        self._w(0x84, self._r(0x84) & ~0x10)  # active low
        self._w(0x0B, 0x01)
        for seq, start in ((0x01, 0x41), (0x02, 0x01)):  # VHV, then phase calibration
            self._w(0x01, seq)
            self._w(0x00, start)
            self._wait_ready(3 * BUDGET_US)
            self._w(0x0B, 0x01)
            self._w(0x00, 0x00)
        self._w(0x01, 0xE8)
        self._running = False
        self._ok = True

    def _start(self, continuous):
        self._page(self._stop)
        self._w(0x00, 0x02 if continuous else 0x01)

    # ---- sampling ----
    def next_due_us(self):
        if self._started is not None and self.mode == "single":
            return self._check
        return self._due

    def poll(self, now, fresh=False):
        if self._started is not None and self.mode == "single":
            if now >= self._check:
                self._collect(now)
            return
        Ranger.poll(self, now, fresh)

    def measure(self, now):
        starting = not self._ok
        try:
            if not self._ok:
                self.init()
            if self.mode == "single":
                self._start(False)
                self._started = self.clock()
                self._check = self._started + BUDGET_US
                return
            if not self._running:
                self._start(True)
                self._running = True
                self._started = self.clock()
                return  # the first range comes a budget later
        except OSError as e:
            self._fail(now, e, starting)
            return
        self._started = now - BUDGET_US  # (continuous: the newest ranging)
        self._collect(now)

    def _fail(self, now, e, starting=False):
        bus_fault(self, e, starting)  # (log.py: said once, then counted)
        self.bus_errors += 1
        self._ok = False
        self._started = None
        self.emit(0, None, now)

    def _collect(self, now):
        started = self._started
        try:
            if self._r(0x13) & 0x07 == 0:
                if now - started > 3 * BUDGET_US:
                    self.timeouts += 1
                    report(
                        self,
                        TIMEOUT,
                        "no ranging within 3 budgets (%d ms)" % (3 * BUDGET_US // 1000),
                    )
                    self._ok = False
                    self._started = None
                    self.emit(0, None, now)
                self._check = now + 2000  # (single: looked at again soon)
                return
            status = (self._r(0x14) >> 3) & 0x0F
            hi, lo = self._i2c.readfrom_mem(self.address, 0x1E, 2)
            self._w(0x0B, 0x01)
        except OSError as e:
            self._fail(now, e)
            return
        if self.mode == "single":
            self._started = None
        mm = (hi << 8) | lo
        stamp = started + BUDGET_US // 2
        if status != 11 or mm >= 8190:
            self.emit(0, None, stamp)
        else:
            self.emit(0, mm, stamp)
