"""A `machine` module whose peripherals are simulated at their interfaces, so the firmware's
drivers run byte for byte as on a board: under MicroPython's WebAssembly port (node, host.mjs)
and under CPython (`missing-link board --file ... --runtime cpython`, virtual/boardfile.py).

Pins keep a level and an IRQ handler; a level change made by the world (an encoder phase, a
bouncing bumper) calls the handler at once, as an interrupt between two bytecodes would.
ADC.read_u16 converts the voltage the world puts on the pin as a 12-bit converter does (RP2040)
and scales it to 16 bit; a floating pin (its part absent) wanders, as an open input picks up
whatever is near.  PWM keeps frequency and duty as set.  I2C dispatches to device models by
(bus, address); an absent or busy device does not acknowledge: OSError(EIO), as rp2.  UART keeps
what the world sent (a device at the other end produces it when the firmware looks) and what
the firmware wrote; time_pulse_us asks the device driving that pin for its pulse (none there:
it waits out its timeout, as on a board).  The device models (devices.py: SRF02, MPU-6050,
compasses, VL53L0X, HC-SR04, a GPS receiver, a stepper driver; here the Sharp ranger's curve)
follow their datasheets, with their own tables: the drivers are checked against them, not
against themselves.

WORLD holds everything; a test drives it through the simulator host's control channel.  The
MicroPython subset only (this file runs inside the board's interpreter).
"""

import time

from . import simcost

try:  # MicroPython: the port's tick counter (it wraps; ticks_diff copes)
    ticks_us = time.ticks_us
    ticks_ms = time.ticks_ms  # (wraps at 2^30 ms: 12.4 days)
    ticks_add = time.ticks_add
    ticks_diff = time.ticks_diff
    sleep_us = time.sleep_us
except AttributeError:  # CPython: the same over CLOCK_MONOTONIC, as board/clock.py reads it there

    def ticks_us():
        return time.monotonic_ns() // 1000

    def ticks_ms():
        return time.monotonic_ns() // 1000000

    def ticks_add(t, delta):
        return t + delta

    def ticks_diff(a, b):
        return a - b

    def sleep_us(us):
        time.sleep(us / 1000000)


# Under simulated time (host.mjs --fast: simtime.py) a peripheral call costs a board's time
# (simcost.py): the call, and what its hardware takes (an ADC conversion, an I2C transfer's bus
# time: a driver that polls a part waits as long in simulated time as on a board).  In real
# time, and under CPython, it takes what the interpreter takes.  The world's own reads of the
# clock (the logs here, the devices) are free: it is not the board's work.
_charge = getattr(time, "charge_ns", None)
if hasattr(time, "now_us"):
    ticks_us = time.now_us  # noqa: F811 - (simulated time: the world's reads are free)
    ticks_ms = time.now_ms  # noqa: F811


def _call(ns=0):
    if _charge is not None:
        _charge(simcost.CALL_NS + ns)


EIO = 5
VREF = 3.3
UNIQUE_ID = b"\xe6\x60\x58\x38\x83\x2a\x4d\x2f"


class _PinState:
    def __init__(self):
        self.level = 0
        self.handler = None
        self.trigger = 0
        self.pin = None
        self.irqs = 0
        self.driven = False  # the world has set this level (a pull-up no longer decides it)


class World:
    def __init__(self):
        self.pins = {}
        self.volts = {}  # pin -> volts at the ADC
        self.adc_q = {}  # pin -> 1/16 mV at the ADC, in integers (the world's: a battery)
        self.sharp = {}  # pin -> distance in mm seen by a GP2Y0A02YK on that ADC pin
        self.pwms = {}  # pin -> PWM
        self.i2c = {}  # (bus, 7-bit address) -> device model
        self.adc_reads = 0
        self.adc_log = []  # ticks_us of the newest ADC reads (at most log_cap)
        self.edges = {}  # pin -> [(ticks_us, level)] of an output's changes (at most log_cap)
        self.watchers = {}  # pin -> [fn(level)]: devices that see the firmware drive a pin
        self.uarts = {}  # UART id -> UART
        self.uart_sources = {}  # UART id -> device producing its bytes (.produce(now_us))
        self.pulses = {}  # pin -> device answering time_pulse_us on it (.pulse(level, timeout))
        self.devices = {}  # transducer name -> its device model (devices.py), for tests
        self.names = []  # the board file's transducer names, in its order (parts.py)
        self.floating = {}  # ADC pin -> (volts, noise state) of an input left open
        self.unique_id = UNIQUE_ID  # what machine.unique_id() says (the board's serial)
        # entries kept in adc_log and each edges list: the simulator's own memory and garbage,
        # which under a board's heap (host.mjs --heap) the firmware pays for: none kept there
        self.log_cap = 2000

    def pin(self, pin_id):
        st = self.pins.get(pin_id)
        if st is None:
            st = self.pins[pin_id] = _PinState()
        return st

    def set_level(self, pin_id, level):
        st = self.pin(pin_id)
        st.driven = True
        level = 1 if level else 0
        if st.level == level:
            return
        st.level = level
        mask = Pin.IRQ_RISING if level else Pin.IRQ_FALLING
        if st.handler is not None and st.trigger & mask:
            st.irqs += 1
            st.handler(st.pin)

    # ---- encoder phases: Gray code A/B, one edge per step ----
    def encoder_steps(self, pin_a, pin_b, steps):
        # (A, B) go (0, 0) (1, 0) (1, 1) (0, 1): A leads B forward; integers only (the world
        # turns wheels from between the firmware's steps: nothing of it in the board's heap)
        d = 1 if steps > 0 else -1
        left = steps * d  # (a while loop: a range object would be garbage in the board's heap)
        while left > 0:
            left -= 1
            a, b = self.pin(pin_a).level, self.pin(pin_b).level
            n = (((b << 1) | (a ^ b)) + d) & 3
            if ((n >> 1) ^ n) & 1 != a:
                self.set_level(pin_a, ((n >> 1) ^ n) & 1)
            else:
                self.set_level(pin_b, n >> 1)

    def encoder_glitch(self, pin_a, pin_b):
        # both phases change between two interrupts: an edge the firmware cannot have seen
        st_a, st_b = self.pin(pin_a), self.pin(pin_b)
        st_a.level ^= 1
        st_b.level ^= 1
        if st_b.handler is not None:
            st_b.handler(st_b.pin)

    def bounce(self, pin_id, level, bounces=5):
        for _ in range(bounces):
            self.set_level(pin_id, level)
            self.set_level(pin_id, 1 - level)
        self.set_level(pin_id, level)

    def adc_volts(self, pin_id):
        if pin_id in self.sharp:
            return sharp_volts(self.sharp[pin_id])
        if pin_id in self.floating:
            return self._wander(pin_id)
        return self.volts.get(pin_id, 0.0)

    def float_adc(self, pin_id):
        # the pin's part is absent: the input is left open
        self.floating[pin_id] = (VREF / 2, (0x9E3779B9 ^ (pin_id * 2654435761)) & 0xFFFFFFFF or 1)

    def _wander(self, pin_id):
        # An open ADC input: no datasheet says what it reads (the sample capacitor's charge,
        # what couples in from neighbours); here a random walk over the whole range in steps of
        # up to 0.2 V (xorshift32 seeded by the pin: every run reads the same).
        v, s = self.floating[pin_id]
        s ^= (s << 13) & 0xFFFFFFFF
        s ^= s >> 17
        s ^= (s << 5) & 0xFFFFFFFF
        v = min(VREF, max(0.0, v + ((s & 0xFFFF) / 65535 - 0.5) * 0.4))
        self.floating[pin_id] = (v, s)
        return v

    def pulse_us(self, pin_id):
        p = self.pwms.get(pin_id)
        return None if p is None else p._duty_ns / 1000

    def watch(self, pin_id, fn):
        self.watchers.setdefault(pin_id, []).append(fn)

    def duty(self, pin_id):
        # a PWM output's duty 0..1 (0 when it is not a PWM output)
        p = self.pwms.get(pin_id)
        if p is None or not p._freq:
            return 0.0
        return p._duty_ns / (1000000000 / p._freq)


WORLD = World()


# ---- the GP2Y0A02YK0F's output (datasheet fig. "analog output voltage vs distance", typical,
# white paper): (cm, V), linear between points; closer than 15 cm the output falls again.
_SHARP = (
    (0, 0.0),
    (5, 1.6),
    (10, 2.35),
    (15, 2.75),
    (20, 2.5),
    (30, 2.0),
    (40, 1.55),
    (50, 1.25),
    (60, 1.05),
    (70, 0.9),
    (80, 0.8),
    (90, 0.72),
    (100, 0.65),
    (120, 0.55),
    (150, 0.41),
    (200, 0.35),
    (300, 0.3),
)


def sharp_volts(mm):
    cm = mm / 10
    for i in range(1, len(_SHARP)):
        c1, v1 = _SHARP[i]
        if cm <= c1:
            c0, v0 = _SHARP[i - 1]
            return v0 + (v1 - v0) * (cm - c0) / (c1 - c0)
    return _SHARP[-1][1]


class Pin:
    IN = 0
    OUT = 1
    OPEN_DRAIN = 2
    PULL_UP = 1
    PULL_DOWN = 2
    IRQ_FALLING = 4
    IRQ_RISING = 8

    def __init__(self, pin_id, mode=-1, pull=None, value=None):
        self.id = pin_id
        st = WORLD.pin(pin_id)
        st.pin = self
        if pull == Pin.PULL_UP and not st.driven:
            st.level = 1
        if value is not None:
            st.level = 1 if value else 0

    def value(self, v=None):
        _call()
        st = WORLD.pin(self.id)
        if v is None:
            return st.level
        level = 1 if v else 0
        changed = level != st.level
        if changed and WORLD.log_cap:
            log = WORLD.edges.setdefault(self.id, [])
            log.append((ticks_us(), level))
            if len(log) > WORLD.log_cap:
                log.pop(0)
        st.level = level
        if changed:
            for fn in WORLD.watchers.get(self.id, ()):
                fn(level)
        return None

    def irq(self, handler=None, trigger=IRQ_FALLING | IRQ_RISING, hard=False):
        st = WORLD.pin(self.id)
        st.handler = handler
        st.trigger = trigger


class ADC:
    def __init__(self, pin):
        self.id = pin.id if isinstance(pin, Pin) else pin

    def read_u16(self):
        _call(simcost.ADC_NS)
        WORLD.adc_reads += 1
        if WORLD.log_cap:
            WORLD.adc_log.append(ticks_us())
            if len(WORLD.adc_log) > WORLD.log_cap:
                WORLD.adc_log.pop(0)
        q = WORLD.adc_q.get(self.id)
        if q is not None and self.id not in WORLD.floating:  # (integers: no float made)
            code12 = max(0, min(4095, (q * 4095 + 26400) // 52800))  # (3300 mV x 16)
        else:
            v = max(0.0, min(VREF, WORLD.adc_volts(self.id)))
            code12 = int(v / VREF * 4095 + 0.5)
        return (code12 << 4) | (code12 >> 8)  # as rp2 scales 12 to 16 bit


class PWM:
    def __init__(self, pin, freq=None, duty_ns=None):
        self.id = pin.id
        self._freq = 0
        self._duty_ns = 0
        WORLD.pwms[self.id] = self
        if freq is not None:
            self.freq(freq)
        if duty_ns is not None:
            self.duty_ns(duty_ns)

    def freq(self, f=None):
        _call()
        if f is None:
            return self._freq
        if not 8 <= f <= 62500000:
            raise ValueError("freq out of range")
        self._freq = f
        return None

    def duty_ns(self, ns=None):
        _call()
        if ns is None:
            return self._duty_ns
        if ns < 0:
            raise ValueError("duty must be >= 0")
        period = 1000000000 // self._freq if self._freq else 0
        self._duty_ns = min(ns, period) if period else ns
        return None

    def duty_u16(self, d=None):
        _call()
        period = 1000000000 // self._freq
        if d is None:
            return self._duty_ns * 65535 // period
        self._duty_ns = d * period // 65535
        return None

    def deinit(self):
        WORLD.pwms.pop(self.id, None)


class I2C:
    def __init__(self, bus_id, scl=None, sda=None, freq=400000, timeout=50000):
        self.id = bus_id
        self.freq = freq

    def _bus(self, nbytes):
        # the call, and the address and data bytes, 9 bits each, and start/stop on the bus
        _call((nbytes + 1) * 9 * (1000000000 // self.freq))  # (small ints: no garbage)

    def _dev(self, addr):
        dev = WORLD.i2c.get((self.id, addr))
        # (off: a part the world made fail, worldfeed.py)
        if dev is None or getattr(dev, "off", False) or not dev.ack():
            raise OSError(EIO)
        return dev

    def scan(self):
        return sorted(a for (b, a), d in WORLD.i2c.items() if b == self.id and d.ack())

    def writeto_mem(self, addr, reg, buf):
        self._bus(1 + len(buf))
        self._dev(addr).write(reg, bytes(buf))

    def readfrom_mem(self, addr, reg, n):
        self._bus(3 + n)  # (the register written, a repeated start, the address again)
        return bytes(self._dev(addr).read(reg, n))

    def writeto(self, addr, buf, stop=True):
        buf = bytes(buf)
        self._bus(len(buf))
        dev = self._dev(addr)
        if buf:
            dev.write(buf[0], buf[1:])
        return len(buf)

    def readfrom(self, addr, n, stop=True):
        self._bus(n)
        return bytes(self._dev(addr).read(None, n))


class UART:
    def __init__(self, uart_id, baudrate=9600, tx=None, rx=None, rxbuf=256, **kw):
        self.id = uart_id
        self.baudrate = baudrate
        self.rxbuf = rxbuf
        self.rx = bytearray()  # from the device, not read yet
        self.tx = bytearray()  # what the firmware wrote
        self.overruns = 0
        WORLD.uarts[uart_id] = self

    def feed(self, data):
        # the device sends: bytes beyond the receive buffer are lost, as on a real UART
        room = self.rxbuf - len(self.rx)
        if len(data) > room:
            self.overruns += len(data) - room
            data = data[:room]
        self.rx.extend(data)

    def _produce(self):
        src = WORLD.uart_sources.get(self.id)
        if src is not None and not getattr(src, "off", False):
            src.produce(ticks_us())

    def any(self):
        _call()
        self._produce()
        return len(self.rx)

    def read(self, n=None):
        _call()
        self._produce()
        if not self.rx:
            return None
        n = len(self.rx) if n is None else min(n, len(self.rx))
        out = bytes(self.rx[:n])
        self.rx = self.rx[n:]
        return out

    def write(self, data):
        _call()
        self.tx.extend(data)
        return len(data)


def time_pulse_us(pin, pulse_level, timeout_us=1000000):
    # -2: no pulse started within the timeout, -1: it did not end within it (MicroPython's)
    _call()
    dev = WORLD.pulses.get(pin.id)
    if dev is None or getattr(dev, "off", False):  # nothing drives the pin: the wait runs out
        sleep_us(timeout_us)
        return -1 if WORLD.pin(pin.id).level == pulse_level else -2
    return dev.pulse(pulse_level, timeout_us)


def seeded_unique_id(seed):
    # a simulated chip's id from a seed: 8 bytes, as an RP2040's flash id (`board --file --seed
    # N`, host.mjs --seed N: each simulated board its own)
    import hashlib

    return hashlib.sha256(("missing-link sim board %d" % seed).encode()).digest()[:8]


def seed_unique_id(seed):
    WORLD.unique_id = seeded_unique_id(seed)


def unique_id():
    return WORLD.unique_id


def freq():
    return 125000000


def reset():
    raise SystemExit("machine.reset()")
