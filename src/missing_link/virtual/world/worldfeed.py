"""The world's hands inside the simulator: what the world (missing_link/world/, run beside the
firmware by virtual/worldlink.py) puts into the board's simulated devices and reads of its
actuators, in small integers only.  The MicroPython subset only: under MicroPython node calls
these between the firmware's steps, and a call with small integers that stores small integers
allocates nothing in the board's heap (a float would: an object a value), so the firmware's
heap goes as it would without the world (tests/test_world_mpy.py counts it); under CPython the
world link calls them directly, the same code.

Parts are numbered as attach() was given them (preallocated: MAX_PARTS).  Units: mm (a ranger;
-1: nothing in reach), an IMU's acceleration in 1/16384 g and turn rate in 1/131 deg/s (the
MPU-6050's LSB at its finest ranges), a field in 1/12000 gauss (the QMC5883L's finest), a fix in
whole degrees and 1e-7 degree, 0.1 m, 0.1 knot, 0.1 degree and 0.1 HDOP, a pack in mV.  An
actuator reads as one integer: motor() pin_devices.motor_code's, servo() its pulse in µs (-1:
none), stepper() its microstep position, stepper_on() 1 while enabled.  An encoder's edge
comes with its time (step_at): under simulated time (simtime.py) the board's clock reads that
time while the interrupt handler runs, as a board's handler runs when the edge comes.
"""

from .machine import WORLD
from .pin_devices import motor_code

MAX_PARTS = 32
TICKS_MAX = 0x3FFFFFFF  # (the board clock's wrap: simtime.py; a small integer as written)
HCSR04, SRF02, VL53L0X, SHARP, IMU, COMPASS, GPS, BATTERY = 0, 1, 2, 3, 4, 5, 6, 7
MOTOR, SERVO, STEPPER, ENCODER = 8, 9, 10, 11
_devs = [None] * MAX_PARTS  # index -> device model (an ADC or PWM part: its pin)
_kinds = [0] * MAX_PARTS
clock = None  # simtime (--fast) or heldtime (real time): the clock an edge's handler reads
release = None  # heldtime's: the port's clock again after the edges


def attach(i, t, kind, pin):
    # part i: the board file's transducer number t, of kind (above), on pin (ADC, PWM parts)
    dev = WORLD.devices.get(WORLD.names[t])
    _devs[i] = dev if dev is not None else pin
    _kinds[i] = kind


def ranger(i, mm):
    dev, kind = _devs[i], _kinds[i]
    if kind == SHARP:  # (a voltage on its pin: machine.py's curve of the part)
        WORLD.sharp[dev] = mm if mm >= 0 else 3000
    elif kind == VL53L0X:
        dev.target = mm >= 0
        dev.distance_mm = mm if mm >= 0 else 8190
    elif kind == SRF02:
        dev.echo = mm >= 0
        dev.distance_mm = mm if mm >= 0 else 0
    else:
        dev.distance_mm = mm if mm >= 0 else None


def imu(i, ax, ay, az, gx, gy, gz):
    dev = _devs[i]
    a, g = dev.accel, dev.gyro
    a[0], a[1], a[2] = ax, ay, az
    g[0], g[1], g[2] = gx, gy, gz


def field(i, x, y, z):
    f = _devs[i].field
    f[0], f[1], f[2] = x, y, z


def fix(i, lat_deg, lat_e7, lon_deg, lon_e7, alt_dm, speed_dkn, course_dd, sats, hdop_d):
    dev = _devs[i]
    dev.lat_deg, dev.lat_e7 = lat_deg, lat_e7
    dev.lon_deg, dev.lon_e7 = lon_deg, lon_e7
    dev.alt_dm, dev.speed_dkn, dev.course_dd = alt_dm, speed_dkn, course_dd
    dev.sats, dev.hdop_d = sats, hdop_d


def volts(i, mv):
    _devs[i].set_mv(mv)


def off(i, flag):
    # a part that fails silent: it does not acknowledge, echo or send; an ADC part's pin floats
    dev, kind = _devs[i], _kinds[i]
    if kind == SHARP or kind == BATTERY:
        pin = dev if kind == SHARP else dev.pin
        if flag:
            WORLD.float_adc(pin)
        else:
            WORLD.floating.pop(pin, None)
        return
    dev.off = flag == 1


def step_at(t, pin_a, pin_b, d):
    # an encoder's edge (d: +1 forward, -1 back) at simulated µs t (wrapped as the clock is)
    if clock is not None:
        clock.set_now(t)
    WORLD.encoder_steps(pin_a, pin_b, d)


def steps_at(pin_a, pin_b, d, n, t0, span):
    # n edges the same way, spread evenly from t0 to t0 + span (µs; t0 wrapped as the clock
    # is): the k-th at t0 + span * k // (n - 1), made by adding (span * k is not a small integer
    # on a 32-bit port once span * n passes 2^30: a second's span and a few hundred edges), each
    # sum below TICKS_MAX and wrapped as the clock is.  Each edge is machine.encoder_steps' one
    # step and set_level's delivery, written out here with the two pins' states taken once (as
    # calls, the simulator's own work was 26 µs an edge, more than the firmware's handler's)
    # (no range object, no tuple of four: nothing of the world's garbage in the board's heap)
    st_a, st_b = WORLD.pin(pin_a), WORLD.pin(pin_b)
    set_now = clock.set_now if clock is not None else None
    rest = TICKS_MAX - t0
    gaps = n - 1 if n > 1 else 1
    whole = span // gaps
    part = span - whole * gaps  # (0 <= part < gaps)
    dt = 0
    carry = 0
    k = 0
    while k < n:
        if set_now is not None:
            set_now(t0 + dt if dt <= rest else dt - rest - 1)
        a, b = st_a.level, st_b.level
        g = (((b << 1) | (a ^ b)) + d) & 3  # (A, B) in Gray code, a step on
        if ((g >> 1) ^ g) & 1 != a:  # (A leads B forward: one of them changes)
            st, level = st_a, a ^ 1
        else:
            st, level = st_b, g >> 1
        st.driven = True
        st.level = level
        # (machine.Pin.IRQ_RISING 8, IRQ_FALLING 4)
        if st.handler is not None and st.trigger & (8 if level else 4):
            st.irqs += 1
            st.handler(st.pin)
        dt += whole
        carry += part
        if carry >= gaps:
            carry -= gaps
            dt += 1
        k += 1
    if release is not None:  # (heldtime: the port's clock again)
        release()


def motor(i):
    return motor_code(_devs[i])


def servo(i):
    p = WORLD.pwms.get(_devs[i])
    if p is None or not p._duty_ns:
        return -1
    return p._duty_ns // 1000


def stepper(i):
    return _devs[i].position


def stepper_on(i):
    return 1 if _devs[i].enabled() else 0
