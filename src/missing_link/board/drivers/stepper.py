# A stepper motor through a step/dir microstepping driver (Allegro A3967 as the thesis cites,
# A4988, TI DRV8825): one (micro)step per rising edge on `step_pin` (high at least 1 µs; the
# A3967 asks 1 µs, the DRV8825 1.9 µs), the direction on `dir_pin` (set 200 ns before the edge),
# `enable_pin` active low (optional).  The microstep resolution is set by the driver's MS pins
# (`microsteps`: what they are wired to; 8 at most on the A3967, 16 on the A4988, 32 on the
# DRV8825); `steps_per_rev` is the motor's full steps (200 for 1.8 degree).
#
# Commanded over J2A with one float32, as every actuator takes one value: with the run-time key
# `mode` = position, the revolutions to go to (absolute); with `mode` = velocity, the speed to
# turn at in rev/s (signed; 0 stops, decelerating).  NaN (the transducer's N/A, from a raw call:
# the host does not send N/A commands) stops at once and lets go (enable off).
# Moves follow a trapezoid: speed changes by at most `accel` rev/s^2 up to `max_speed` rev/s,
# and a move to a position decelerates to arrive at rest.  Steps are timed from the board loop
# (poll at each step's time): a few kHz at most in MicroPython; a faster stepper wants the
# RP2040's PIO or the ESP32's RMT.  Channels: 0 position (rev), 1 speed (rev/s), reported every
# REPORT_US while moving and when it stops; the position is counted from power-up (a stepper
# has no absolute sensor).
# Failsafe (failsafe.py): stop at once (no ramp: the host is gone) and let go.

import math
import struct

from . import Driver

REPORT_US = 50000
MICROSTEPS = (1, 2, 4, 8, 16, 32)
MODES = ("position", "velocity")
GOTO, SPEED, STOP = 0, 1, 2


class Stepper(Driver):
    PREFIX = "stepper"
    MODEL = "A4988"
    CHANNELS = 2
    DTYPE = "float"
    NA = float("nan")
    OPTIONS = {"unit": "rev", "kind": "actuator"}
    CONFIG = (
        ("max_speed", "float", (0.01, 50.0), False),
        ("accel", "float", (0.01, 1000.0), False),
        ("microsteps", "enum", MICROSTEPS, True),  # wired on the driver's MS pins
        ("mode", "enum", MODES, False),
    )

    def __init__(
        self,
        machine,
        clock,
        step_pin,
        dir_pin,
        enable_pin=None,
        steps_per_rev=200,
        microsteps=1,
        max_speed=2.0,
        accel=4.0,
        mode="position",
        invert=False,
    ):
        if microsteps not in MICROSTEPS:
            raise ValueError("stepper microsteps: one of %s" % (MICROSTEPS,))
        if mode not in MODES:
            raise ValueError("stepper mode: position or velocity")
        self.mode = mode
        self.clock = clock
        self._step = machine.Pin(step_pin, machine.Pin.OUT, value=0)
        self._dir = machine.Pin(dir_pin, machine.Pin.OUT, value=0)
        self._en = None
        if enable_pin is not None:
            self._en = machine.Pin(enable_pin, machine.Pin.OUT, value=1)  # off until moved
        self.microsteps = microsteps
        self.per_rev = steps_per_rev * microsteps  # (micro)steps per revolution
        self.max_speed = max_speed
        self.accel = accel
        self._invert = invert
        self.position = 0  # steps
        self.speed = 0.0  # steps/s, signed
        self._mode = STOP
        self._goal = 0.0  # steps (GOTO) or steps/s (SPEED)
        self._next = None  # board µs of the next step
        self._last_step = None
        self._reported = None
        self.enabled = False
        self.commands = 0

    def get_config(self, key):
        return getattr(self, key)

    def set_config(self, key, value):
        setattr(self, key, value)

    def _enable(self, on):
        self.enabled = on
        if self._en is not None:
            self._en.value(0 if on else 1)

    def _report(self, now):
        self._reported = now
        if self._cb is not None:  # (no floats made for nobody)
            self.emit(0, self.position / self.per_rev, now)
            self.emit(1, self.speed / self.per_rev, now)

    def command(self, payload):
        if len(payload) != 4:
            return 0xFF, b"expects one float32 (rev, or rev/s)"
        value = struct.unpack("<f", payload)[0]
        self.commands += 1
        if value != value:  # N/A: let go
            self.make_safe()
            return 0, b""
        if abs(value) > 1e6 or abs(value) * self.per_rev >= 2147483648:  # (an int32 of steps
            return 0xFF, b"too far"  # on AVR; the infinities too: one behaviour everywhere)
        mode = GOTO if self.mode == "position" else SPEED
        if mode == SPEED and abs(value) > self.max_speed:
            return 0xFF, b"faster than max_speed"
        now = self.clock()
        self._mode = mode
        self._goal = value * self.per_rev
        if mode == GOTO or value != 0:
            self._enable(True)
        if self._next is None and self._wants_motion():
            self._next = now
        self._report(now)
        return 0, b""

    def _wants_motion(self):
        if self._mode == GOTO:
            return round(self._goal) != self.position or self.speed != 0
        if self._mode == SPEED:
            return self._goal != 0 or self.speed != 0
        return self.speed != 0

    def _target_speed(self):
        # the speed to head for now (steps/s, signed)
        vmax = self.max_speed * self.per_rev
        a = self.accel * self.per_rev
        if self._mode == SPEED:
            return self._goal
        if self._mode == STOP:
            return 0.0
        togo = round(self._goal) - self.position
        if togo == 0:
            return 0.0
        braking = self.speed * self.speed / (2 * a)  # steps to stop from here
        if self.speed != 0 and abs(togo) <= braking + 1 and (togo > 0) == (self.speed > 0):
            return 0.0  # time to slow down
        return vmax if togo > 0 else -vmax

    def next_due_us(self):
        return self._next

    def poll(self, now):
        if self._next is None or now < self._next:
            return
        a = self.accel * self.per_rev
        v0 = math.sqrt(2 * a)  # the speed after the first step from rest (v^2 = 2as)
        dt = (now - self._last_step) / 1000000 if self._last_step is not None else 0.0
        want = self._target_speed()
        v = self.speed
        if v == 0:
            v = v0 if want > 0 else -v0 if want < 0 else 0.0
        else:
            dv = a * max(dt, 1 / abs(v))
            if want > v:
                v = min(want, v + dv)
            elif want < v:
                v = max(want, v - dv)
        togo = round(self._goal) - self.position if self._mode == GOTO else None
        if v != 0 and self.speed != 0:
            if (v > 0) != (self.speed > 0):
                v = 0.0  # through zero: stop first, the next step starts the other way
            elif want == 0 and abs(v) < v0:
                # Slower than a step from rest (a rounding residue would crawl for ever): stop,
                # or with steps to go that way, go on at that speed.
                v = math.copysign(v0, v) if togo and (togo > 0) == (v > 0) else 0.0
        if v == 0 or (togo == 0 and abs(v) <= v0 * 1.5):
            self.speed = 0.0
            self._next = None
            self._last_step = None
            if togo is None or togo != 0:
                if self._wants_motion():
                    self._next = now  # (turning round)
            self._report(now)
            return
        self.speed = v
        forward = v > 0
        self._dir.value(1 if forward != self._invert else 0)
        self._step.value(1)
        self._step.value(0)
        self.position += 1 if forward else -1
        self._last_step = now
        self._next = now + int(1000000 / abs(v))
        if self._reported is None or now - self._reported >= REPORT_US:
            self._report(now)

    def make_safe(self):
        # the failsafe (failsafe.py), and mode 3: no more steps, the driver let go
        self._mode = STOP
        self.speed = 0.0
        self._next = None
        self._last_step = None
        self._enable(False)
        self._report(self.clock())
