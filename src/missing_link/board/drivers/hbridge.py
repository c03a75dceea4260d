# A DC motor through an H-bridge, in either of the two ways bridges are driven:
#   pwm_pin + dir_pin  (PWM/DIR or EN/PH bridges: Pololu DRV8838/MAX14870, Cytron MD10C): the
#                      duty's size on PWM, its sign on DIR; duty 0 leaves the motor coasting
#                      (the bridge's outputs off, as these bridges do with PWM low);
#   in1 + in2          (L298N, TB6612 without its PWM pin, DRV8833): forward = IN1 PWM with IN2
#                      low, reverse = IN2 PWM with IN1 low; stop = both low (coast) or both high
#                      (brake: the windings shorted through the low side; `stop` = brake).
# Commanded over J2A with one float32 duty, -1..1 (the sign is the direction); NaN or out of
# range is refused.  The applied duty moves towards the commanded one by at most `ramp` per
# second (0: at once), so a reversal does not slam the gearbox or brown out the supply.  The
# transducer reports the applied duty, stamped when it took effect (while ramping, every
# RAMP_STEP_US at most).  `freq` is the PWM frequency (20 kHz: above hearing).
# Failsafe (failsafe.py): duty 0 at once (no ramp) with the `stop` the keys say.

import struct

from . import Driver

RAMP_STEP_US = 20000


class HBridge(Driver):
    PREFIX = "motor"
    MODEL = "H-bridge"
    CHANNELS = 1
    DTYPE = "float"
    NA = float("nan")
    OPTIONS = {"unit": "duty", "kind": "actuator"}
    CONFIG = (
        ("ramp", "float", (0.0, 1000.0), False),
        ("stop", "enum", ("coast", "brake"), False),
        ("freq", "int", (100, 100000), False),
    )

    def __init__(
        self,
        machine,
        clock,
        pwm_pin=None,
        dir_pin=None,
        in1=None,
        in2=None,
        freq=20000,
        ramp=4.0,
        stop="coast",
        invert=False,
    ):
        self.clock = clock
        if pwm_pin is not None and dir_pin is not None and in1 is None and in2 is None:
            self._pwm = machine.PWM(machine.Pin(pwm_pin))
            self._dir = machine.Pin(dir_pin, machine.Pin.OUT, value=0)
            self._in = None
        elif in1 is not None and in2 is not None and pwm_pin is None and dir_pin is None:
            self._in = (machine.PWM(machine.Pin(in1)), machine.PWM(machine.Pin(in2)))
            self._pwm = self._dir = None
        else:
            raise ValueError("hbridge: give pwm_pin and dir_pin, or in1 and in2")
        self._sign = -1 if invert else 1
        self.freq = freq
        self._set_freq(freq)
        self.ramp = ramp
        self.stop = stop
        self._check(stop)
        self.target = 0.0
        self.duty = 0.0
        self._last_us = None
        self._due = None
        self.commands = 0
        self._apply(0.0)

    def _check(self, stop):
        if stop == "brake" and self._in is None:
            raise ValueError("hbridge: stop = brake needs in1 and in2 (a PWM/DIR bridge coasts)")

    def _set_freq(self, f):
        for p in (self._pwm,) if self._in is None else self._in:
            p.freq(f)

    def get_config(self, key):
        return getattr(self, key)

    def set_config(self, key, value):
        if key == "freq":
            self._set_freq(value)
        setattr(self, key, value)

    def check_config(self):
        if self.stop == "brake" and self._in is None:
            return "stop = brake needs in1 and in2 (a PWM/DIR bridge coasts)"
        if self.duty == 0:
            self._apply(0.0)  # a new stop mode shows at once
        return None

    def _apply(self, d):
        # d: -1..1 as the motor should see it
        d = d * self._sign
        u16 = int(abs(d) * 65535 + 0.5)
        if self._in is None:
            self._dir.value(1 if d < 0 else 0)
            self._pwm.duty_u16(u16)
            return
        fwd, rev = self._in
        if d == 0:
            level = 65535 if self.stop == "brake" else 0
            fwd.duty_u16(level)
            rev.duty_u16(level)
        elif d > 0:
            rev.duty_u16(0)
            fwd.duty_u16(u16)
        else:
            fwd.duty_u16(0)
            rev.duty_u16(u16)

    def _report(self, now):
        self.emit(0, self.duty, now)

    def command(self, payload):
        if len(payload) != 4:
            return 0xFF, b"expects one float32 duty, -1..1"
        d = struct.unpack("<f", payload)[0]
        if not -1.0 <= d <= 1.0:  # (NaN too)
            return 0xFF, b"duty must be -1..1"
        self.commands += 1
        self.target = d
        now = self.clock()
        self._last_us = now
        if self.ramp <= 0:
            self.duty = d
            self._apply(d)
            self._report(now)
        else:
            self._step(now)
        return 0, b""

    def _step(self, now):
        dt = (now - self._last_us) / 1000000 if self._last_us is not None else 0.0
        self._last_us = now
        most = self.ramp * max(dt, RAMP_STEP_US / 1000000)
        delta = self.target - self.duty
        if abs(delta) <= most:
            self.duty = self.target
        else:
            self.duty += most if delta > 0 else -most
        self._apply(self.duty)
        self._report(now)
        self._due = None if self.duty == self.target else now + RAMP_STEP_US

    def next_due_us(self):
        return self._due

    def poll(self, now):
        if self._due is not None and now >= self._due:
            self._step(now)

    def make_safe(self):
        # the failsafe (failsafe.py): stopped at once, coasting or braking as `stop` says
        self.target = self.duty = 0.0
        self._due = None
        self._apply(0.0)
        self._report(self.clock())
