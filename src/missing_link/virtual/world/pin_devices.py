"""The simulated devices on plain pins (devices.py says how the models are made): the HC-SR04
ranger (a trigger pulse in, an echo pulse out), a stepper driver (step and direction), a DC
motor (PWM, or two H-bridge inputs) and a battery pack behind a divider on an ADC pin.  The
MicroPython subset only.
"""

from .machine import WORLD, sleep_us


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


def _duty_e4(pin):
    # a PWM output's duty in 1/10000, in integers (0 when it is not a PWM output)
    p = WORLD.pwms.get(pin)
    if p is None or not p._freq:
        return 0
    return min(10000, p._duty_ns // max(1, 1000000000 // p._freq // 10000))


def motor_code(m):
    # Motor.state() in one small integer, for the world (worldfeed.py): mode x 100000 + 50000 +
    # duty in 1/10000 (modes: 0 coast, 1 drive, 2 brake, 3 shoot-through); no float made
    if m.in1 is None:
        d = _duty_e4(m.pwm_pin)
        if d == 0:
            return 50000
        return 150000 + (-d if WORLD.pin(m.dir_pin).level else d)
    a, b = _duty_e4(m.in1), _duty_e4(m.in2)
    if a >= 9990 and b >= 9990:
        return 250000
    if a == 0 and b == 0:
        return 50000
    if b == 0 or a == 0:
        return 150000 + a - b
    return 350000 + a - b


class BatteryPack:
    # A battery pack behind a resistor divider (pack + -> r_top -> pin -> r_bottom -> ground):
    # the ADC pin sees volts * r_bottom / (r_top + r_bottom).  The pack's voltage is what a test
    # (set_volts) or the world (set_mv, in integers: worldfeed.py) sets; its discharge and sag
    # are the world's (missing_link/world), the divider's tolerance is not modelled.
    def __init__(self, pin, r_top=10000.0, r_bottom=3300.0, volts=7.4):
        self.pin = pin
        self.divider = r_bottom / (r_top + r_bottom)
        self._k = int(round(self.divider * 16384))  # (the divider in 1/16384)
        self.set_volts(volts)

    def set_volts(self, volts):
        self.set_mv(int(round(volts * 1000)))

    def set_mv(self, mv):
        self.mv = mv
        WORLD.adc_q[self.pin] = (mv * self._k) >> 10  # the pin in 1/16 mV

    @property
    def volts(self):
        return self.mv / 1000
