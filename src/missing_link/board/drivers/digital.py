# Digital input (a bumper, a limit switch) with debouncing.
#
# A pin interrupt on both edges stamps the first edge of a burst; once the level has been stable
# for debounce_ms, the new level is reported with that first edge's stamp (when the contact
# actually happened, not when the bouncing stopped).  Bounces that return to the reported level
# report nothing.  `active_low` inverts (a switch to ground with the pull-up: pressed = 1).
# Optionally the level is also reported every 1 / rate_hz s as a heartbeat (rate_hz = 0: off).

from . import Driver


class DigitalIn(Driver):
    PREFIX = "gpio"
    MODEL = "switch"
    CHANNELS = 1
    DTYPE = "uint8_t"  # 0/1; bool has no room for N/A
    NA = 0xFF
    OPTIONS = {"kind": "sensor"}
    # rate_hz: the heartbeat (0: only changes are reported)
    CONFIG = (
        ("debounce_ms", "int", (0, 1000), False),
        ("rate_hz", "float", (0.0, 100.0), False),
    )

    def __init__(self, machine, clock, pin, pull="up", active_low=True, debounce_ms=20, rate_hz=0):
        Pin = machine.Pin
        pull_mode = {"up": Pin.PULL_UP, "down": Pin.PULL_DOWN, None: None, "none": None}[pull]
        self.clock = clock
        self._pin = Pin(pin, Pin.IN, pull_mode)
        self._invert = 1 if active_low else 0
        self._debounce_us = int(debounce_ms * 1000)
        self._period_us = int(1000000 / rate_hz) if rate_hz else None
        self.level = self._read()
        self._first_edge_us = None
        self._last_edge_us = None
        self._next_beat = None
        self.edges = 0
        self._pin.irq(handler=self._edge, trigger=Pin.IRQ_RISING | Pin.IRQ_FALLING)

    def get_config(self, key):
        if key == "debounce_ms":
            return self._debounce_us // 1000
        if key == "rate_hz":
            return round(1000000.0 / self._period_us, 3) if self._period_us else 0.0
        raise ValueError("no key " + key)

    def set_config(self, key, value):
        if key == "debounce_ms":
            self._debounce_us = int(value) * 1000
        elif key == "rate_hz":
            self._period_us = int(1000000 / value) if value else None
            self._next_beat = None
        else:
            raise ValueError("no key " + key)

    def _read(self):
        return self._pin.value() ^ self._invert

    def set_cb(self, fn):
        Driver.set_cb(self, fn)
        fn(0, self.level, self.clock())  # the level at start-up

    def _edge(self, _pin):
        now = self.clock()
        self.edges += 1
        if self._first_edge_us is None:
            self._first_edge_us = now
        self._last_edge_us = now

    def next_due_us(self):
        due = self._next_beat
        if self._last_edge_us is not None:
            t = self._last_edge_us + self._debounce_us
            due = t if due is None or t < due else due
        return due

    def poll(self, now):
        last = self._last_edge_us
        if last is not None and now - last >= self._debounce_us:
            first = self._first_edge_us
            self._first_edge_us = self._last_edge_us = None
            level = self._read()
            if level != self.level:
                self.level = level
                self._emit(first)
                return
        if self._period_us is not None:
            if self._next_beat is None:
                self._next_beat = now + self._period_us
            elif now >= self._next_beat:
                self._next_beat = now + self._period_us
                if self._first_edge_us is None:  # never report a level that is still bouncing
                    self._emit(now)

    def _emit(self, stamp):
        self.emit(0, self.level, stamp)
