"""The simulated devices at their interfaces, for the firmware's drivers under MicroPython or
CPython (machine.py holds the pins, buses and UARTs they sit on).  Each follows its datasheet
with its own tables and arithmetic, so a driver is checked against the part, not against
itself; what a model leaves out is said in its comment.  Tests reach them through WORLD
(WORLD.i2c[(bus, address)], WORLD.uart_sources[id], WORLD.pulses[pin], WORLD.devices); parts.py
puts them where a board file says they are wired.  The MicroPython subset only.
"""

from .machine import WORLD, sleep_us, ticks_add, ticks_diff, ticks_us


def _now_us():
    return ticks_us()


class SRF02:
    # Devantech SRF02 (datasheet "SRF02 Ultrasonic range finder", I2C mode): 6 registers; a
    # ranging takes 65 ms during which it does not acknowledge; range in the unit asked for.
    REVISION = 6
    BUSY_US = 65000

    def __init__(self, bus, address=0x70):
        self.bus = bus
        self.address = address
        self.distance_cm = 100.0
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
            cm = self.distance_cm if self.echo else 0
            self._range = {0x50: int(cm / 2.54), 0x51: int(cm), 0x52: int(cm * 58.3)}[cmd]
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


class MPU6050:
    # InvenSense MPU-6050 (register map rev 4.2): asleep at power-up (PWR_MGMT_1 = 0x40), data
    # registers read 0 while asleep; scaled by GYRO_CONFIG / ACCEL_CONFIG's FS_SEL bits.
    def __init__(self, bus, address=0x68):
        self.regs = bytearray(128)
        self.regs[0x6B] = 0x40
        self.regs[0x75] = 0x68
        self.accel_g = (0.0, 0.0, 1.0)
        self.gyro_dps = (0.0, 0.0, 0.0)
        self.temp_c = 25.0
        WORLD.i2c[(bus, address)] = self

    def ack(self):
        return True

    def write(self, reg, data):
        for i, b in enumerate(data):
            self.regs[reg + i] = b

    def _sample(self):
        if self.regs[0x6B] & 0x40:
            return bytes(14)
        afs = (self.regs[0x1C] >> 3) & 3
        fs = (self.regs[0x1B] >> 3) & 3
        a = [int(round(g * (16384 >> afs))) for g in self.accel_g]
        w = [int(round(d * 131.0 / (1 << fs))) for d in self.gyro_dps]
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


def _bytes_i16(values, big):
    out = bytearray()
    for v in values:
        v = max(-32768, min(32767, v)) & 0xFFFF
        out.extend((v >> 8, v & 0xFF) if big else (v & 0xFF, v >> 8))
    return out


class HMC5883L:
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
        self.field_gauss = (0.2, -0.1, 0.4)  # x y z
        self._gain = 1  # the gain the next reading is made with
        self._data = bytearray(6)
        WORLD.i2c[(bus, address)] = self

    def ack(self):
        return True

    def write(self, reg, data):
        for i, b in enumerate(data):
            if reg + i < 10:
                self.regs[reg + i] = b

    def read(self, reg, n):
        reg = 0 if reg is None else reg
        if reg <= 3 < reg + n and self.regs[2] & 3 == 0:
            lsb = self.GAINS[self._gain]
            x, y, z = (round(g * lsb) for g in self.field_gauss)
            raw = [v if -2048 <= v <= 2047 else -4096 for v in (x, z, y)]
            self._data = _bytes_i16(raw, True)
            self._gain = self.regs[1] >> 5
        regs = bytes(self.regs[:3]) + bytes(self._data) + bytes(self.regs[9:13])
        return regs[reg : reg + n]


class QMC5883L:
    # QST QMC5883L (datasheet 1.0): data X Y Z, little-endian, at 0-5; status (6) bit 0 data
    # ready, bit 1 overflow (a raw value beyond the 16 bits); control 1 (9): mode bits 1-0 (01
    # continuous; 00 standby: the data do not change), rate bits 3-2, range bits 5-4 (2 G: 12000
    # LSB/G, 8 G: 3000); control 2 (0x0A) bit 7 is a soft reset (registers to their defaults);
    # chip id 0x0D reads 0xFF.
    LSB = (12000, 3000)

    def __init__(self, bus, address=0x0D):
        self.regs = bytearray(14)
        self.regs[0x0D] = 0xFF
        self.field_gauss = (0.2, -0.1, 0.4)
        self.resets = 0
        WORLD.i2c[(bus, address)] = self

    def ack(self):
        return True

    def write(self, reg, data):
        for i, b in enumerate(data):
            r = reg + i
            if r == 0x0A and b & 0x80:
                self.regs[:0x0D] = bytes(0x0D)
                self.resets += 1
            elif r < 0x0D:
                self.regs[r] = b

    def read(self, reg, n):
        reg = 0 if reg is None else reg
        if reg <= 6 and self.regs[9] & 3 == 1:
            lsb = self.LSB[(self.regs[9] >> 4) & 1]
            raw = [round(g * lsb) for g in self.field_gauss]
            over = any(v < -32768 or v > 32767 for v in raw)
            self.regs[0:6] = _bytes_i16(raw, False)
            self.regs[6] = 0x01 | (0x02 if over else 0)
        out = bytes(self.regs[reg : reg + n])
        if reg <= 6 < reg + n:
            self.regs[6] &= ~0x01  # read: no longer new
        return out


class VL53L0X:
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

    def ack(self):
        return True

    def _paged(self):
        return self._page_regs[1] == 1

    def write(self, reg, data):
        for i, b in enumerate(data):
            self._write1(reg + i, b)

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


class HCSR04:
    # HC-SR04 ("Ultrasonic Ranging Module HC-SR04"): a high pulse on TRIG (the model sees the
    # firmware drive the pin) starts a ranging; ECHO is then high for the sound's round trip at
    # 331.3 + 0.606 T m/s, 2 cm to 4 m; with nothing in range it stays high 38 ms.
    # time_pulse_us on ECHO gets that width, and takes that long (the firmware's loop waits as
    # it would); without a trigger pulse first there is no echo (-2).  The wasm port's clock
    # counts whole ms, so the trigger pulse's 10 µs is not checked.
    NONE_US = 38000

    def __init__(self, trig, echo):
        self.distance_mm = 1000  # None: nothing in range
        self.temperature_c = 20.0
        self._armed = False
        self.rangings = 0
        WORLD.watch(trig, self._on_trig)
        WORLD.pulses[echo] = self

    def _on_trig(self, level):
        if level == 0:
            self._armed = True  # the trigger pulse ended: the burst goes out

    def echo_us(self):
        if self.distance_mm is None or not 20 <= self.distance_mm <= 4000:
            return self.NONE_US
        c = 331.3 + 0.606 * self.temperature_c
        return 2 * self.distance_mm / 1000 / c * 1000000

    def pulse(self, level, timeout_us):
        if not self._armed or level != 1:
            sleep_us(timeout_us)
            return -2
        self._armed = False
        self.rangings += 1
        width = self.echo_us()
        if width > timeout_us:
            sleep_us(timeout_us)
            return -1
        sleep_us(int(width))
        return int(width + 0.5)


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
        self.lat, self.lon, self.alt = 48.1173, 11.516667, 545.4
        self.quality, self.sats, self.hdop = 1, 8, 0.9
        self.speed_kn, self.course = 22.4, 84.4
        self.bad_every = 0
        self.sent = 0
        self.utc0 = NMEA_EXAMPLE_UTC
        self.pps_at = []  # ticks_us of the PPS edges (newest last, at most 20)
        self.edges = []  # (ticks_us, UTC second) of the same edges
        self._mark, self._base = _now_us(), 0  # a whole second since it was made, and which
        self._sec = -1
        self._out = b""  # this second's sentences
        self._out_t0 = 0
        self._fed = 0
        WORLD.uart_sources[uart] = self

    def _coord(self, deg, width):
        d = int(abs(deg))
        minutes = (abs(deg) - d) * 60
        return ("%02d" if width == 2 else "%03d") % d + "%07.4f" % minutes

    def _sentences(self, utc):
        t, (y, mo, d) = utc % 86400, civil_date(utc // 86400)
        hms = "%02d%02d%02d.00" % (t // 3600, (t // 60) % 60, t % 60)
        date = "%02d%02d%02d" % (d, mo, y % 100)
        ns, ew = ("N" if self.lat >= 0 else "S"), ("E" if self.lon >= 0 else "W")
        lat, lon = self._coord(self.lat, 2), self._coord(self.lon, 3)
        fixed = self.quality > 0
        rmc = "GPRMC,%s,%s,%s,%s,%s,%s,%05.1f,%05.1f,%s,003.1,W" % (
            hms, "A" if fixed else "V", lat if fixed else "", ns if fixed else "",
            lon if fixed else "", ew if fixed else "", self.speed_kn, self.course, date,
        )  # fmt: skip
        gga = "GPGGA,%s,%s,%s,%s,%s,%d,%02d,%.1f,%s,M,46.9,M,," % (
            hms, lat if fixed else "", ns if fixed else "", lon if fixed else "",
            ew if fixed else "", self.quality, self.sats, self.hdop,
            ("%.1f" % self.alt) if fixed else "",
        )  # fmt: skip
        out = ""
        for body in (rmc, gga):
            self.sent += 1
            out += _nmea(body, self.bad_every and self.sent % self.bad_every == 0)
        return out.encode()

    def produce(self, now):
        k = ticks_diff(now, self._mark) // 1000000  # (from a mark moved on: ticks_diff spans 537 s)
        self._mark, self._base = ticks_add(self._mark, k * 1000000), self._base + k
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


class StepperDriver:
    # A step/dir driver (A3967, A4988, DRV8825): a rising edge on STEP moves one microstep in
    # DIR's direction (high: forward) while ENABLE is low (no enable pin: always).  It counts
    # what it was told; the motor is not modelled (no lost steps, no stall).
    def __init__(self, step, dir_pin, enable=None):
        self.dir_pin = dir_pin
        self.enable = enable
        self.position = 0
        self.steps = 0
        self.ignored = 0  # edges while disabled
        WORLD.watch(step, self._on_step)

    def enabled(self):
        return self.enable is None or WORLD.pin(self.enable).level == 0

    def _on_step(self, level):
        if not level:
            return
        if not self.enabled():
            self.ignored += 1
            return
        self.steps += 1
        self.position += 1 if WORLD.pin(self.dir_pin).level else -1


class Motor:
    # What an H-bridge's inputs make of a DC motor: PWM/DIR bridges drive at PWM's duty in
    # DIR's direction (high: reverse) and coast at duty 0; IN1/IN2 bridges drive forward at
    # IN1's duty with IN2 low, reverse at IN2's with IN1 low, coast with both low and brake with
    # both high.  state() -> (signed duty, "drive" | "coast" | "brake").
    def __init__(self, pwm_pin=None, dir_pin=None, in1=None, in2=None):
        self.pwm_pin, self.dir_pin, self.in1, self.in2 = pwm_pin, dir_pin, in1, in2

    def state(self):
        if self.in1 is None:
            d = WORLD.duty(self.pwm_pin)
            if d == 0:
                return 0.0, "coast"
            return (-d if WORLD.pin(self.dir_pin).level else d), "drive"
        a, b = WORLD.duty(self.in1), WORLD.duty(self.in2)
        if a >= 0.999 and b >= 0.999:
            return 0.0, "brake"
        if a == 0 and b == 0:
            return 0.0, "coast"
        if b == 0:
            return a, "drive"
        if a == 0:
            return -b, "drive"
        return a - b, "shoot-through"


class BatteryPack:
    # A battery pack behind a resistor divider (pack + -> r_top -> pin -> r_bottom -> ground):
    # the ADC pin sees volts * r_bottom / (r_top + r_bottom).  The pack's voltage is what a test
    # sets (set_volts); discharge, sag under load and the divider's tolerance are not modelled.
    def __init__(self, pin, r_top=10000.0, r_bottom=3300.0, volts=7.4):
        self.pin = pin
        self.divider = r_bottom / (r_top + r_bottom)
        self.set_volts(volts)

    def set_volts(self, volts):
        self.volts = volts
        WORLD.volts[self.pin] = volts * self.divider
