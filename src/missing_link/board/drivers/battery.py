# A battery's voltage through a resistor divider on an ADC (pack + -> r_top -> pin -> r_bottom
# -> ground), and its charge estimated from the voltage.
#
# Each sample: the median of `reads` conversions (machine.ADC.read_u16, against `vref`) times
# the divider's ratio (r_top + r_bottom) / r_bottom is the pack voltage; divided by `cells` (in
# series) it is looked up, linearly between points, in the chemistry's curve of resting voltage
# per cell against charge (`chemistry`: li-ion, lifepo4, nimh, lead-acid; or linear from
# `cell_empty` to `cell_full` volts).  A voltage reads the load too: under current it sags and
# the charge reads low; a divider is no fuel gauge (no current, no temperature).
# Channels (float): 0 pack voltage (V), 1 charge (0..1); both N/A when the pin reads 0 V (no
# battery on it).  Published as sensor_msgs/msg/BatteryState too (ros/standard); name
# the chemistry in the board file's `model` (e.g. "2S LiPo") and the host says its technology.
# Run-time keys: rate_hz, ratio (calibrate the divider against a meter), cells, chemistry.

from . import Periodic

# resting voltage per cell -> charge, typical curves at room temperature, lowest first
CURVES = {
    "li-ion": ((3.0, 0.0), (3.3, 0.05), (3.5, 0.1), (3.6, 0.2), (3.7, 0.4), (3.8, 0.55),
               (3.9, 0.7), (4.0, 0.8), (4.1, 0.9), (4.2, 1.0)),
    "lifepo4": ((2.5, 0.0), (3.0, 0.1), (3.2, 0.2), (3.25, 0.3), (3.3, 0.5), (3.32, 0.7),
                (3.35, 0.9), (3.4, 1.0)),
    "nimh": ((1.0, 0.0), (1.1, 0.05), (1.2, 0.2), (1.25, 0.5), (1.3, 0.8), (1.4, 1.0)),
    "lead-acid": ((1.93, 0.0), (1.98, 0.2), (2.02, 0.4), (2.06, 0.6), (2.10, 0.8),
                  (2.13, 1.0)),
}  # fmt: skip
CHEMISTRIES = ("li-ion", "lifepo4", "nimh", "lead-acid", "linear")


def charge(curve, volts):
    # the fraction at `volts` on a curve of (volts, fraction), clamped to its ends
    if volts <= curve[0][0]:
        return curve[0][1]
    for k in range(1, len(curve)):
        v1, f1 = curve[k]
        if volts <= v1:
            v0, f0 = curve[k - 1]
            return f0 + (f1 - f0) * (volts - v0) / (v1 - v0)
    return curve[-1][1]


class Battery(Periodic):
    PREFIX = "battery"
    MODEL = "voltage divider"
    CHANNELS = 2
    DTYPE = "float"
    NA = float("nan")
    OPTIONS = {"unit": "V", "kind": "sensor"}
    CONFIG = (
        ("rate_hz", "float", (0.1, 100.0), False),
        ("ratio", "float", (1.0, 100.0), False),
        ("cells", "int", (1, 24), False),
        ("chemistry", "enum", CHEMISTRIES, False),
    )
    PLAIN = ("ratio", "cells", "chemistry")

    def __init__(
        self,
        machine,
        clock,
        pin,
        r_top=10000.0,
        r_bottom=3300.0,
        vref=3.3,
        cells=1,
        chemistry="li-ion",
        cell_empty=3.0,
        cell_full=4.2,
        rate_hz=1,
        reads=5,
    ):
        Periodic.__init__(self, clock, rate_hz)
        if not (r_top >= 0 and r_bottom > 0):
            raise ValueError("battery: r_top >= 0 and r_bottom > 0 (ohms)")
        if chemistry not in CHEMISTRIES:
            raise ValueError("battery: chemistry one of %s" % (CHEMISTRIES,))
        if not (cells >= 1 and cell_full > cell_empty > 0):
            raise ValueError("battery: cells >= 1 and cell_full > cell_empty > 0")
        self._adc = machine.ADC(machine.Pin(pin))
        self._lsb = vref / 65535.0
        self.ratio = (r_top + r_bottom) / r_bottom
        self.cells = int(cells)
        self.chemistry = chemistry
        self._linear = ((cell_empty, 0.0), (cell_full, 1.0))
        self._reads = max(1, reads)

    def curve(self):
        return self._linear if self.chemistry == "linear" else CURVES[self.chemistry]

    def measure(self, now):
        r = sorted(self._adc.read_u16() for _ in range(self._reads))
        raw = r[len(r) // 2]
        if raw < 16:  # below the first code of a 12-bit converter: nothing on the pin
            self.emit(0, None, now)
            self.emit(1, None, now)
            return
        volts = raw * self._lsb * self.ratio
        self.emit(0, volts, now)
        self.emit(1, charge(self.curve(), volts / self.cells), now)
