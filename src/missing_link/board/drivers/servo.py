# Hobby servo (e.g. Hitec HS-645MG) on a PWM output: 50 Hz frame, the pulse width sets the angle.
#
# Commanded over J2A with one int8 (-127..127 = -range_deg..+range_deg, as the thesis's servo):
# the pulse is centre_us + value / 127 * half_span_us, clamped to [min_us, max_us] so a wrong
# command can never drive the horn into its end stop.  -128 is the N/A value and is refused.
# The servo cannot report where it is, so the transducer reports the commanded value (stamped
# when the new pulse width took effect); until the first command it outputs no pulse at all
# (the servo stays limp) and reports nothing.  Failsafe (failsafe.py): `safe` = hold keeps the
# last pulse (the servo holds where it is), limp stops the pulses (reported as N/A).

import struct

from . import Driver


class Servo(Driver):
    PREFIX = "servo"
    MODEL = "HS-645MG"
    CHANNELS = 1
    DTYPE = "int8_t"
    NA = -128
    OPTIONS = {"unit": "deg", "kind": "actuator", "scale": "0.708661"}
    CONFIG = (
        ("min_us", "int", (500, 2500), False),
        ("max_us", "int", (500, 2500), False),
        ("centre_us", "int", (500, 2500), False),
        ("span_us", "int", (100, 2000), False),
        ("safe", "enum", ("hold", "limp"), False),
    )

    def __init__(
        self,
        machine,
        clock,
        pin,
        freq=50,
        min_us=900,
        max_us=2100,
        centre_us=1500,
        span_us=1200,
        safe="hold",
    ):
        if not (min_us < centre_us < max_us):
            raise ValueError("servo: need min_us < centre_us < max_us")
        if safe not in ("hold", "limp"):
            raise ValueError("servo safe: hold or limp")
        self.safe = safe
        self.clock = clock
        self._pwm = machine.PWM(machine.Pin(pin))
        self._pwm.freq(freq)
        self._pwm.duty_ns(0)
        self._frame_ns = 1000000000 // freq
        self.min_us = min_us
        self.max_us = max_us
        self.centre_us = centre_us
        self.half_span_us = span_us / 2
        self.pulse_us = None
        self._value = None  # the last commanded value
        self.commands = 0

    def get_config(self, key):
        if key == "span_us":
            return int(self.half_span_us * 2)
        if key in ("min_us", "max_us", "centre_us", "safe"):
            return getattr(self, key)
        raise ValueError("no key " + key)

    def set_config(self, key, value):
        if key == "span_us":
            self.half_span_us = value / 2
        elif key in ("min_us", "max_us", "centre_us", "safe"):
            setattr(self, key, value)
        else:
            raise ValueError("no key " + key)

    def check_config(self):
        # After a set: the limits must bracket the centre; a pulse already out is re-clamped.
        if not (self.min_us < self.centre_us < self.max_us):
            return "need min_us < centre_us < max_us (%d, %d, %d)" % (
                self.min_us,
                self.centre_us,
                self.max_us,
            )
        if self.pulse_us is not None and self._value is not None:
            self.pulse_us = self.pulse_for(self._value)
            self._pwm.duty_ns(self.pulse_us * 1000)
        return None

    def pulse_for(self, value):
        us = self.centre_us + value * self.half_span_us / 127
        return max(self.min_us, min(self.max_us, int(us + 0.5)))

    def command(self, payload):
        if len(payload) != 1:
            return 0xFF, b"expects one int8"
        value = struct.unpack("<b", payload)[0]
        if value == -128:
            return 0xFF, b"-128 is N/A"
        self._value = value
        self.pulse_us = self.pulse_for(value)
        self._pwm.duty_ns(self.pulse_us * 1000)
        self.commands += 1
        self.emit(0, value, self.clock())
        return 0, struct.pack("<H", self.pulse_us)

    def make_safe(self):
        # the failsafe (failsafe.py): hold the last pulse, or go limp
        if self.safe == "limp" and self.pulse_us is not None:
            self._pwm.duty_ns(0)
            self.pulse_us = None
            self._value = None
        self.emit(0, self._value, self.clock())
