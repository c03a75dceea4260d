# Quadrature encoder (e.g. HEDS-5500/6500 on a wheel): x4 decoding from pin interrupts on both
# edges of both phases.
#
# Each edge reads both phases and looks the (previous, current) state pair up in a transition
# table: +1/-1 for a legal step, 0 for no change; a pair where both phases changed means an edge
# was missed (too fast for the interrupt latency) and is counted in `errors`, and the count
# since is unreliable: the next report is N/A and the position is re-based on the next edge.
# The count is reported every period with the stamp of the newest edge that changed it, or the
# report time when it did not move.  The value wraps like a hardware counter in the declared
# type (int32 by default: 2**31 counts, hours at any wheel speed).

from ..log import OVERRUN, report
from . import Periodic

# index: previous state (A<<1|B) * 4 + current state
_STEP = (0, -1, 1, 0, 1, 0, 0, -1, -1, 0, 0, 1, 0, 1, -1, 0)


class Quadrature(Periodic):
    PREFIX = "quad"
    MODEL = "quadrature"
    CHANNELS = 1
    DTYPE = "int32_t"
    NA = -2147483648
    OPTIONS = {"unit": "count", "kind": "sensor"}
    CONFIG = Periodic.CONFIG + (("reverse", "bool", None, False),)

    def __init__(self, machine, clock, pin_a, pin_b, rate_hz=50, pull="up", reverse=False):
        Periodic.__init__(self, clock, rate_hz)
        Pin = machine.Pin
        pull_mode = {"up": Pin.PULL_UP, "down": Pin.PULL_DOWN, None: None, "none": None}[pull]
        self._a = Pin(pin_a, Pin.IN, pull_mode)
        self._b = Pin(pin_b, Pin.IN, pull_mode)
        self._sign = -1 if reverse else 1
        self._state = (self._a.value() << 1) | self._b.value()
        self.count = 0
        self.errors = 0
        self._bad = False
        self._edge_us = None
        trig = Pin.IRQ_RISING | Pin.IRQ_FALLING
        self._a.irq(handler=self._edge, trigger=trig)
        self._b.irq(handler=self._edge, trigger=trig)

    def _edge(self, _pin):
        # Interrupt context (a soft IRQ on rp2/esp32): no allocation beyond the clock's.
        s = (self._a.value() << 1) | self._b.value()
        prev = self._state
        if s == prev:
            return
        self._state = s
        d = _STEP[(prev << 2) | s]
        if d == 0:
            self.errors += 1
            self._bad = True
            return
        self.count += d * self._sign
        self._edge_us = self.clock()

    def get_config(self, key):
        if key == "reverse":
            return self._sign < 0
        return Periodic.get_config(self, key)

    def set_config(self, key, value):
        if key == "reverse":
            self._sign = -1 if value else 1
        else:
            Periodic.set_config(self, key, value)

    def measure(self, now):
        if self._bad:
            self._bad = False
            report(self, OVERRUN, "edges missed (both phases changed at once: too fast)")
            self.emit(0, None, now)  # an edge was missed: this count is not trustworthy
            return
        stamp = self._edge_us if self._edge_us is not None else now
        self._edge_us = None
        c = self.count & 0xFFFFFFFF
        self.emit(0, c - 0x100000000 if c & 0x80000000 else c, stamp)
