# InvenSense MPU-6050 IMU on I2C (address 0x68, 0x69 with AD0 high): accelerometer, gyroscope
# and die temperature.
#
# Start-up: WHO_AM_I (0x75) must read 0x68; PWR_MGMT_1 (0x6B) = 0x01 wakes the chip on the X gyro's
# PLL (the datasheet's recommended clock); CONFIG (0x1A) sets the digital low-pass filter;
# GYRO_CONFIG (0x1B) and ACCEL_CONFIG (0x1C) set the full-scale ranges.  Each sample is one
# 14-byte burst read from ACCEL_XOUT_H (0x3B): ax ay az temp gx gy gz, big-endian int16, so all
# seven come from the same instant.  Scaling (register map rev 4.2): accel 16384 LSB/g at +-2 g,
# halving per range step; gyro 131 LSB/(deg/s) at +-250 deg/s, halving per step; temperature
# raw / 340 + 36.53 degC.  Published as float: m/s^2, rad/s, degC.  A bus error gives N/A on all
# channels; the chip is re-initialised on the next sample (it may have browned out).

import struct

from ..log import WrongPart, bus_fault
from . import Periodic

G = 9.80665
DEG = 3.141592653589793 / 180
ACCEL_RANGES = (2, 4, 8, 16)
GYRO_RANGES = (250, 500, 1000, 2000)


class MPU6050(Periodic):
    PREFIX = "imu"
    MODEL = "MPU-6050"
    CHANNELS = 7
    DTYPE = "float"
    NA = float("nan")
    # channels: ax ay az (m/s2), die temperature (degC), gx gy gz (rad/s)
    OPTIONS = {"kind": "sensor", "unit": "SI"}
    # New ranges and filter are written to the chip before the next sample.
    CONFIG = Periodic.CONFIG + (
        ("accel_g", "enum", ACCEL_RANGES, False),
        ("gyro_dps", "enum", GYRO_RANGES, False),
        ("dlpf", "int", (0, 6), False),
    )

    def __init__(
        self, machine, clock, i2c, address=0x68, rate_hz=100, accel_g=2, gyro_dps=250, dlpf=3
    ):
        Periodic.__init__(self, clock, rate_hz)
        if accel_g not in ACCEL_RANGES or gyro_dps not in GYRO_RANGES:
            raise ValueError("mpu6050: accel_g in %s, gyro_dps in %s" % (ACCEL_RANGES, GYRO_RANGES))
        self._i2c = i2c
        self.address = address
        self._afs = ACCEL_RANGES.index(accel_g)
        self._fs = GYRO_RANGES.index(gyro_dps)
        self._dlpf = dlpf & 7
        self._accel = G / (16384 >> self._afs)
        self._gyro = DEG / (131.0 / (1 << self._fs))
        self._ok = False
        self.bus_errors = 0

    def get_config(self, key):
        if key == "accel_g":
            return ACCEL_RANGES[self._afs]
        if key == "gyro_dps":
            return GYRO_RANGES[self._fs]
        if key == "dlpf":
            return self._dlpf
        return Periodic.get_config(self, key)

    def set_config(self, key, value):
        if key == "accel_g":
            self._afs = ACCEL_RANGES.index(value)
            self._accel = G / (16384 >> self._afs)
        elif key == "gyro_dps":
            self._fs = GYRO_RANGES.index(value)
            self._gyro = DEG / (131.0 / (1 << self._fs))
        elif key == "dlpf":
            self._dlpf = value
        else:
            Periodic.set_config(self, key, value)
            return
        self._ok = False  # the chip gets the new setting before the next sample

    def init(self):
        i2c, a = self._i2c, self.address
        who = i2c.readfrom_mem(a, 0x75, 1)[0]
        if who != 0x68:
            raise WrongPart("WHO_AM_I is 0x%02x, not an MPU-6050 (0x68)" % who)
        i2c.writeto_mem(a, 0x6B, b"\x01")
        i2c.writeto_mem(a, 0x1A, bytes((self._dlpf,)))
        i2c.writeto_mem(a, 0x1B, bytes((self._fs << 3,)))
        i2c.writeto_mem(a, 0x1C, bytes((self._afs << 3,)))
        self._ok = True

    def measure(self, now):
        starting = not self._ok
        try:
            if not self._ok:
                self.init()
            stamp = self.clock()
            ax, ay, az, t, gx, gy, gz = struct.unpack(
                ">7h", self._i2c.readfrom_mem(self.address, 0x3B, 14)
            )
        except OSError as e:
            bus_fault(self, e, starting)  # (log.py: said once, then counted)
            self.bus_errors += 1
            self._ok = False
            for ch in range(7):
                self.emit(ch, None, now)
            return
        k, w = self._accel, self._gyro
        values = (ax * k, ay * k, az * k, t / 340.0 + 36.53, gx * w, gy * w, gz * w)
        for ch in range(7):
            self.emit(ch, values[ch], stamp)
