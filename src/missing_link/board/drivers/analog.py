# Analog input on an ADC: the 16-bit reading (machine.ADC.read_u16, whatever the converter's own
# resolution) or, with millivolts=True, the voltage against vref in mV.  Median of `reads`
# conversions per sample, to shed single spikes.

from . import Periodic


class AnalogIn(Periodic):
    PREFIX = "adc"
    MODEL = "adc"
    CHANNELS = 1
    DTYPE = "uint16_t"
    NA = 0xFFFF
    OPTIONS = {"kind": "sensor"}
    CONFIG = Periodic.CONFIG + (("reads", "int", (1, 15), False),)
    PLAIN = ("reads",)

    def __init__(self, machine, clock, pin, rate_hz=100, vref=3.3, millivolts=False, reads=1):
        Periodic.__init__(self, clock, rate_hz)
        self._adc = machine.ADC(machine.Pin(pin))
        self._mv = vref * 1000.0 / 65535.0 if millivolts else None
        self.reads = max(1, reads)

    def measure(self, now):
        r = sorted(self._adc.read_u16() for _ in range(self.reads))
        raw = r[len(r) // 2]
        self.emit(0, raw if self._mv is None else min(0xFFFE, int(raw * self._mv + 0.5)), now)
