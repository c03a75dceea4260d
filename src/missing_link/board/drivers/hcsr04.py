# HC-SR04 ultrasonic ranger on two pins (datasheet "Ultrasonic Ranging Module HC-SR04").
#
# A high pulse of at least 10 µs on `trig_pin` starts a ranging: the module sends eight 40 kHz
# cycles and then holds `echo_pin` high for the sound's round trip ("range = high level time *
# velocity / 2"; 2 cm to 4 m; the datasheet asks for 60 ms between measurements).  The echo's
# width is measured with machine.time_pulse_us, which blocks the loop for at most the round trip
# to `max_range_cm` (23 ms at 4 m); the speed of sound is 331.3 + 0.606 * T m/s at the configured
# `temperature_c`.  No echo in that time (nothing in range; many modules then hold echo high for
# 38 ms) gives N/A, as does a range below 2 cm.  The sample is stamped when the sound reflected:
# the echo's end (when time_pulse_us returned) minus half the flight, as the SRF02's.

from ..log import NO_ANSWER, report
from . import Ranger, ranger_options

TRIG_US = 10
MIN_MM = 20


def sound_m_per_s(temperature_c):
    return 331.3 + 0.606 * temperature_c


class HCSR04(Ranger):
    PREFIX = "ultrasonic"
    MODEL = "HC-SR04"
    OPTIONS = ranger_options("mm", "20", "4000")
    CONFIG = (
        ("rate_hz", "float", (0.1, 16.6), False),  # 60 ms between rangings at the most
        ("temperature_c", "float", (-40.0, 85.0), False),
        ("max_range_cm", "int", (20, 400), False),
    )
    PLAIN = ("temperature_c", "max_range_cm")
    # Not kept off the board's instants (pacing.py): a ranging lasts as long as its echo, the
    # distance (2.3 ms at 40 cm to 33 ms with nothing in range), so its longest lately is no
    # forecast of the next, and one that cannot fit the grid's room covers as many instants
    # from any start; it measures when due, as before
    PACED = False

    def __init__(
        self, machine, clock, trig_pin, echo_pin, rate_hz=10, temperature_c=20.0, max_range_cm=400
    ):
        Ranger.__init__(self, clock, min(rate_hz, 16.6))
        self._machine = machine
        self._trig = machine.Pin(trig_pin, machine.Pin.OUT, value=0)
        self._echo = machine.Pin(echo_pin, machine.Pin.IN)
        self._echo_id = echo_pin
        self.temperature_c = temperature_c
        self.max_range_cm = max_range_cm
        self.timeouts = 0

    def measure(self, now):
        c = sound_m_per_s(self.temperature_c)
        timeout = int(2 * self.max_range_cm / 100 / c * 1000000) + 1000
        self._trig.value(1)
        start = self.clock()
        while self.clock() - start < TRIG_US:
            pass
        self._trig.value(0)
        width = self._machine.time_pulse_us(self._echo, 1, timeout)
        end = self.clock()
        if width < 0:  # -2: the echo never started, -1: it did not end within the range
            self.timeouts += 1
            if width == -2:  # (a module always answers a trigger: absent, unpowered, unwired)
                report(self, NO_ANSWER, "no echo pulse at all (echo pin %s)" % self._echo_id)
            self.emit(0, None, end)
            return
        mm = int(width * c / 2000 + 0.5)  # µs * m/s / 2 -> µm; / 1000 -> mm
        if mm < MIN_MM or mm > self.max_range_cm * 10:
            self.emit(0, None, end)
            return
        self.emit(0, mm, end - width // 2)
