"""The simulated devices on an I2C bus (devices.py says how the models are made): the SRF02
ranger, the MPU-6050 IMU, the HMC5883L and QMC5883L compasses, the VL53L0X time-of-flight ranger,
each at WORLD.i2c[(bus, address)].  The MicroPython subset only.

What the world (worldfeed.py) sets is kept in small integers at each part's finest step (mm,
the MPU-6050's LSB at +-2 g and +-250 deg/s, the QMC5883L's 1/12000 gauss), so it is set and
read into registers without a float: under MicroPython nothing of it in the board's heap.  The
attributes in SI-like units (distance_cm, accel_g, field_gauss ...) are properties over them.
"""

from .machine import WORLD, ticks_add, ticks_diff, ticks_us
from .units import scaled, scaled_xyz


def _now_us():
    return ticks_us()


class _Registers:
    # a part on the bus that acknowledges whenever it is addressed and takes a write as one
    # register after another (_write1: a part with registers that do more says so there)
    def ack(self):
        return True

    def write(self, reg, data):
        for i, b in enumerate(data):
            self._write1(reg + i, b)

    def _write1(self, r, b):
        self.regs[r] = b


class SRF02:
    # Devantech SRF02 (datasheet "SRF02 Ultrasonic range finder", I2C mode): 6 registers; a
    # ranging takes 65 ms during which it does not acknowledge; range in the unit asked for.
    REVISION = 6
    BUSY_US = 65000

    def __init__(self, bus, address=0x70):
        self.bus = bus
        self.address = address
        self.distance_mm = 1000
        self.echo = True  # False: nothing in range (range reads 0)
        self._busy_until = None
        self._range = 0
        self._min = 18
        self._seq = []
        self.rangings = 0
        WORLD.i2c[(bus, address)] = self

    def ack(self):
        if self._busy_until is None:
            return True
        if ticks_diff(_now_us(), self._busy_until) >= 0:
            self._busy_until = None
            return True
        return False

    def write(self, reg, data):
        if reg != 0 or len(data) != 1:
            return
        cmd = data[0]
        if cmd in (0x50, 0x51, 0x52):
            self._seq = []
            self.rangings += 1
            mm = self.distance_mm if self.echo else 0
            if cmd == 0x50:  # inches
                self._range = mm * 10 // 254
            elif cmd == 0x51:
                self._range = mm // 10
            else:  # µs of the round trip, 58.3 a cm
                self._range = mm * 583 // 100
            self._busy_until = ticks_add(_now_us(), self.BUSY_US)
            return
        self._seq.append(cmd)
        if self._seq[:3] == [0xA0, 0xAA, 0xA5][: len(self._seq[:3])] and len(self._seq) == 4:
            new = cmd >> 1
            if cmd & 1 == 0 and 0x70 <= new <= 0x7F:
                del WORLD.i2c[(self.bus, self.address)]
                self.address = new
                WORLD.i2c[(self.bus, new)] = self
            self._seq = []
        elif self._seq != [0xA0, 0xAA, 0xA5][: len(self._seq)]:
            self._seq = []

    distance_cm = scaled("distance_mm", 10)

    def read(self, reg, n):
        regs = [
            self.REVISION,
            0x80,
            (self._range >> 8) & 0xFF,
            self._range & 0xFF,
            0,
            self._min,
        ]
        reg = 0 if reg is None else reg
        return [regs[r] if r < len(regs) else 0 for r in range(reg, reg + n)]


class MPU6050(_Registers):
    # InvenSense MPU-6050 (register map rev 4.2): asleep at power-up (PWR_MGMT_1 = 0x40), data
    # registers read 0 while asleep; scaled by GYRO_CONFIG / ACCEL_CONFIG's FS_SEL bits.
    def __init__(self, bus, address=0x68):
        self.regs = bytearray(128)
        self.regs[0x6B] = 0x40
        self.regs[0x75] = 0x68
        self.accel = [0, 0, 16384]  # LSB at +-2 g (1/16384 g)
        self.gyro = [0, 0, 0]  # LSB at +-250 deg/s (1/131 deg/s)
        self.temp_c = 25.0
        WORLD.i2c[(bus, address)] = self

    def _sample(self):
        if self.regs[0x6B] & 0x40:
            return bytes(14)
        afs = (self.regs[0x1C] >> 3) & 3
        fs = (self.regs[0x1B] >> 3) & 3
        a = [(v + ((1 << afs) >> 1)) >> afs for v in self.accel]  # (rounded)
        w = [(v + ((1 << fs) >> 1)) >> fs for v in self.gyro]
        t = int(round((self.temp_c - 36.53) * 340))
        vals = a + [t] + w
        out = bytearray()
        for v in vals:
            v = max(-32768, min(32767, v)) & 0xFFFF
            out.append(v >> 8)
            out.append(v & 0xFF)
        return out

    def read(self, reg, n):
        if reg == 0x3B:
            return self._sample()[:n]
        return self.regs[reg : reg + n]

    accel_g = scaled_xyz("accel", 16384)
    gyro_dps = scaled_xyz("gyro", 131)


def _bytes_i16(values, big):
    out = bytearray()
    for v in values:
        v = max(-32768, min(32767, v)) & 0xFFFF
        out.extend((v >> 8, v & 0xFF) if big else (v & 0xFF, v >> 8))
    return out


class _Field(_Registers):
    # a magnetometer's field, kept in 1/12000 gauss (the QMC5883L's finest LSB)
    def _init_field(self):
        self.field = [2400, -1200, 4800]  # 0.2, -0.1, 0.4 gauss

    field_gauss = scaled_xyz("field", 12000)


class HMC5883L(_Field):
    # Honeywell HMC5883L (datasheet rev E): identification "H43" at 10-12; configuration B bits
    # 7-5 the gain (1370 ... 230 LSB/gauss); data X Z Y, big-endian, at 3-8, from a 12-bit
    # converter (-2048..2047): beyond it an axis reads -4096.  A new gain shows from the
    # reading after the next one (the datasheet's note).  Mode (2) = 0 is continuous; in the
    # other modes the data registers keep what they held.
    GAINS = (1370, 1090, 820, 660, 440, 390, 330, 230)

    def __init__(self, bus, address=0x1E):
        self.regs = bytearray(13)
        self.regs[0], self.regs[1], self.regs[2] = 0x10, 0x20, 0x01  # power-up: idle
        self.regs[10:13] = b"H43"
        self._init_field()  # x y z
        self._gain = 1  # the gain the next reading is made with
        self._data = bytearray(6)
        WORLD.i2c[(bus, address)] = self

    def _write1(self, r, b):
        if r < 10:
            self.regs[r] = b

    def read(self, reg, n):
        reg = 0 if reg is None else reg
        if reg <= 3 < reg + n and self.regs[2] & 3 == 0:
            lsb = self.GAINS[self._gain]
            x, y, z = ((v * lsb + 6000) // 12000 for v in self.field)
            raw = [v if -2048 <= v <= 2047 else -4096 for v in (x, z, y)]
            self._data = _bytes_i16(raw, True)
            self._gain = self.regs[1] >> 5
        regs = bytes(self.regs[:3]) + bytes(self._data) + bytes(self.regs[9:13])
        return regs[reg : reg + n]


class QMC5883L(_Field):
    # QST QMC5883L (datasheet 1.0): data X Y Z, little-endian, at 0-5; status (6) bit 0 data
    # ready, bit 1 overflow (a raw value beyond the 16 bits); control 1 (9): mode bits 1-0 (01
    # continuous; 00 standby: the data do not change), rate bits 3-2, range bits 5-4 (2 G: 12000
    # LSB/G, 8 G: 3000); control 2 (0x0A) bit 7 is a soft reset (registers to their defaults);
    # chip id 0x0D reads 0xFF.
    LSB = (12000, 3000)

    def __init__(self, bus, address=0x0D):
        self.regs = bytearray(14)
        self.regs[0x0D] = 0xFF
        self._init_field()
        self.resets = 0
        WORLD.i2c[(bus, address)] = self

    def _write1(self, r, b):
        if r == 0x0A and b & 0x80:
            self.regs[:0x0D] = bytes(0x0D)
            self.resets += 1
        elif r < 0x0D:
            self.regs[r] = b

    def read(self, reg, n):
        reg = 0 if reg is None else reg
        if reg <= 6 and self.regs[9] & 3 == 1:
            lsb = self.LSB[(self.regs[9] >> 4) & 1]
            raw = self.field if lsb == 12000 else [(v + 2) >> 2 for v in self.field]
            over = any(v < -32768 or v > 32767 for v in raw)
            self.regs[0:6] = _bytes_i16(raw, False)
            self.regs[6] = 0x01 | (0x02 if over else 0)
        out = bytes(self.regs[reg : reg + n])
        if reg <= 6 < reg + n:
            self.regs[6] &= ~0x01  # read: no longer new
        return out


class VL53L0X(_Registers):
    # ST VL53L0X, the registers the driver's start-up and ranging touch (ST's API, UM2039):
    # model id 0xC0 = 0xEE; the "stop variable" at 0x91 is reached behind the page sequence
    # 0x80 = 1, 0xFF = 1, 0x00 = 0 (while 0xFF = 1, register 0 is the page register, not
    # SYSRANGE_START); SYSRANGE_START (0x00): bit 0 starts a ranging, bit 1 back to back, 0x41
    # the VHV calibration; a ranging (or calibration) takes the 33 ms budget, then the interrupt
    # status (0x13) reads 4 until cleared (0x0B = 1); back to back, the next one starts then.
    # Range status (0x14) bits 6-3: 11 valid, 4 phase fail (nothing in range); range at 0x1E-1F
    # (mm, big-endian).  A ranging started without the stop variable written back since the
    # last page sequence reads status 0 (not valid), so a driver that skips it is seen.
    BUDGET_US = 33000
    STOP = 0x3C

    def __init__(self, bus, address=0x29):
        self.regs = bytearray(256)
        self.regs[0xC0] = 0xEE
        self.regs[0x84] = 0x11
        self.distance_mm = 500
        self.target = True
        self._page_regs = [0, 0]  # 0x80, 0xFF
        self._stop_ok = False
        self._ready_at = None
        self._continuous = False
        self._status = 0
        self.rangings = 0
        WORLD.i2c[(bus, address)] = self

    def _paged(self):
        return self._page_regs[1] == 1

    def _write1(self, r, b):
        if r == 0x80:
            self._page_regs[0] = b
        elif r == 0xFF:
            self._page_regs[1] = b
            if b == 1:
                self._stop_ok = False  # a page sequence: the stop variable is due again
        elif r == 0x91 and self._paged():
            self._stop_ok = b == self.STOP
        elif r == 0x00 and not self._paged():
            if b & 0x03:  # (with the sequence set to 1 or 2 alone: a calibration, not a range)
                self._start(bool(b & 0x02), self.regs[0x01] not in (0x01, 0x02))
            else:
                self._ready_at, self._continuous = None, False
        elif r == 0x0B and b & 1:
            self.regs[0x13] = 0
            if self._continuous:
                self._ready_at = ticks_add(_now_us(), self.BUDGET_US)
        else:
            self.regs[r] = b

    def _start(self, continuous, ranging):
        self._continuous = continuous
        self._ready_at = ticks_add(_now_us(), self.BUDGET_US)
        if ranging:
            self.rangings += 1
            if not self._stop_ok:
                self._status = 0
            else:
                self._status = 11 if self.target else 4
        self._stop_ok = self._stop_ok and continuous

    def read(self, reg, n):
        reg = 0 if reg is None else reg
        ready = self._ready_at is not None and ticks_diff(_now_us(), self._ready_at) >= 0
        if ready and not self.regs[0x13]:
            self.regs[0x13] = 0x04
            self.regs[0x14] = self._status << 3
            mm = self.distance_mm if self.target else 8190
            self.regs[0x1E], self.regs[0x1F] = (mm >> 8) & 0xFF, mm & 0xFF
            if not self._continuous:
                self._ready_at = None
        if reg == 0x91 and self._paged():  # (few allocations: under --heap they are the board's)
            return bytes((self.STOP,)) + bytes(memoryview(self.regs)[reg + 1 : reg + n])
        if reg == 0x00 and not self._paged() and self._ready_at is not None:  # ranging under way
            return bytes((0x01,)) + bytes(memoryview(self.regs)[reg + 1 : reg + n])
        return bytes(memoryview(self.regs)[reg : reg + n])
