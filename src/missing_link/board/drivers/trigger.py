# Trigger output: a camera's, a scope's or a second board's trigger input on a pin.
#
# Commanded over J2A with a u16 width in µs (0: the configured `pulse_us`): one pulse, active
# high unless `active_high` is False.  Through a2jAt (board/timing.py) it fires at a host time:
# cameras and rangers on several boards triggered together.  The rising edge is reported as a
# sample of the pulse's width, stamped when the pin went active (the moment it acted).  A pulse
# up to 1 ms is timed by spinning on the clock (exact); a longer one ends at the first poll
# after it is due (at least its width, longer by the loop's latency).

from . import Driver

SPIN_US = 1000


class Trigger(Driver):
    PREFIX = "gpio"
    MODEL = "trigger"
    CHANNELS = 1
    DTYPE = "uint16_t"
    NA = 0
    OPTIONS = {"unit": "us", "kind": "actuator"}
    CONFIG = (("pulse_us", "int", (1, 65535), False),)

    def __init__(self, machine, clock, pin, pulse_us=10, active_high=True):
        self.clock = clock
        self._on = 1 if active_high else 0
        self._pin = machine.Pin(pin, machine.Pin.OUT, value=1 - self._on)
        self.pulse_us = pulse_us
        self._end = None
        self.fired = 0

    def get_config(self, key):
        return self.pulse_us

    def set_config(self, key, value):
        self.pulse_us = value

    def command(self, payload):
        if len(payload) != 2:
            return 0xFF, b"expects u16 width in us"
        width = (payload[0] | (payload[1] << 8)) or self.pulse_us
        clock = self.clock
        self._pin.value(self._on)
        start = clock()
        self.fired += 1
        if width <= SPIN_US:
            while clock() - start < width:
                pass
            self._pin.value(1 - self._on)
        else:
            self._end = start + width
        self.emit(0, width, start)
        return 0, b""

    def next_due_us(self):
        return self._end

    def poll(self, now):
        if self._end is not None and now >= self._end:
            self._end = None
            self._pin.value(1 - self._on)
