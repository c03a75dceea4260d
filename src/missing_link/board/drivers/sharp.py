# Sharp GP2Y0A02YK0F infrared ranger (20-150 cm) on an ADC input.
#
# The sensor measures continuously (one result every 38.3 ms +/- 9.6 ms, datasheet) and holds its
# output voltage, which falls with distance along the curve of the datasheet's figure (typical,
# white paper, 90 % reflectance).  We read the ADC a few times, take the median, convert to volts
# and interpolate the curve.  Out of range is N/A: above the curve's peak the reading is ambiguous
# (closer than 20 cm gives the same voltage as farther away), below 0.4 V there is no target
# within 150 cm.  For 50 ms after start-up the output is not valid (first measurement), also N/A.
# Reading faster than the sensor updates only repeats values, so the rate is capped at 26 Hz.

from . import Ranger, ranger_options

# (volts, mm) from the datasheet's typical curve, volts falling
CURVE = (
    (2.50, 200),
    (2.00, 300),
    (1.55, 400),
    (1.25, 500),
    (1.05, 600),
    (0.90, 700),
    (0.80, 800),
    (0.72, 900),
    (0.65, 1000),
    (0.60, 1100),
    (0.55, 1200),
    (0.50, 1300),
    (0.45, 1400),
    (0.41, 1500),
)
STARTUP_US = 50000


def volts_to_mm(v):
    # None when outside the curve (too close / nothing in range).
    if v > CURVE[0][0] or v < CURVE[-1][0]:
        return None
    for i in range(1, len(CURVE)):
        v1, d1 = CURVE[i]
        if v >= v1:
            v0, d0 = CURVE[i - 1]
            # distance is close to linear in 1/d against volts: interpolate in 1/d
            f = (v0 - v) / (v0 - v1)
            inv = 1.0 / d0 + f * (1.0 / d1 - 1.0 / d0)
            return int(1.0 / inv + 0.5)
    return None


class SharpGP2Y0A02(Ranger):
    PREFIX = "sharp"
    MODEL = "GP2Y0A02YK"
    OPTIONS = ranger_options("mm")
    CONFIG = (("rate_hz", "float", (0.1, 26.0), False),)  # it updates every 38 ms

    def __init__(self, machine, clock, pin, rate_hz=25, vref=3.3, reads=3):
        Ranger.__init__(self, clock, min(rate_hz, 26))
        self._adc = machine.ADC(machine.Pin(pin))
        self._scale = vref / 65535.0
        self._reads = max(1, reads)
        self._start = clock()

    def volts(self):
        r = sorted(self._adc.read_u16() for _ in range(self._reads))
        return r[len(r) // 2] * self._scale

    def measure(self, now):
        if now - self._start < STARTUP_US:
            self.emit(0, None, now)
            return
        self.emit(0, volts_to_mm(self.volts()), now)
