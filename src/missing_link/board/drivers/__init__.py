# Sensor and actuator drivers for MicroPython's `machine` API (the thesis rig and common parts).
#
# Every driver follows the board rule: set_cb(fn), then fn(channel, value[, stamp_us]) when it
# has a measurement (Driver below: set_cb and emit); drivers that need CPU time implement
# poll(now_us) and next_due_us().  A driver gets the `machine` module and the board clock
# passed in, so nothing here imports a port: the same code runs on RP2040, ESP32, CPython
# (host-side checks) and the simulator.
#
# A driver class carries its descriptor defaults (PREFIX, MODEL, CHANNELS, DTYPE, NA, OPTIONS;
# a Ranger's are said once, below); a board file entry may override any of them.  Its run-time
# configuration (board/config.py) is CONFIG, a tuple of (key, kind, limits, read_only), with
# get_config(key) and set_config(key, value) (a Periodic's PLAIN keys are its attributes of the
# same name, nothing more to do); check_config() (optional) says what is wrong with a
# combination after a set.  An actuator has command(payload) -> (code, reply), registered as the
# J2A function named by the entry's `call`.
#
# DRIVERS maps the board file's `driver` names to module and class, imported only when used (RAM).

DRIVERS = {
    "quadrature": ("encoder", "Quadrature"),
    "sharp_gp2y0a02": ("sharp", "SharpGP2Y0A02"),
    "srf02": ("srf02", "SRF02"),
    "servo": ("servo", "Servo"),
    "digital": ("digital", "DigitalIn"),
    "analog": ("analog", "AnalogIn"),
    "mpu6050": ("mpu6050", "MPU6050"),
    "trigger": ("trigger", "Trigger"),
    "gps_nmea": ("gps_nmea", "GpsNmea"),
    "hmc5883l": ("compass", "HMC5883L"),
    "qmc5883l": ("compass", "QMC5883L"),
    "hbridge": ("hbridge", "HBridge"),
    "stepper": ("stepper", "Stepper"),
    "hcsr04": ("hcsr04", "HCSR04"),
    "vl53l0x": ("vl53l0x", "VL53L0X"),
    "battery": ("battery", "Battery"),
}


def driver_class(name):
    if name not in DRIVERS:
        raise ValueError("unknown driver %s (known: %s)" % (name, ", ".join(sorted(DRIVERS))))
    module, cls = DRIVERS[name]
    mod = __import__(__name__ + "." + module, None, None, [cls])
    return getattr(mod, cls)


class Driver:
    # The board rule, said once: set_cb(fn) (the runtime's), then emit(channel, value[,
    # stamp_us]) hands it a measurement or an actuator's new state; nothing goes out before it.
    _cb = None

    def set_cb(self, fn):
        self._cb = fn

    def emit(self, channel, value, stamp_us=None):
        if self._cb is not None:
            self._cb(channel, value, stamp_us)


class Periodic(Driver):
    # A driver that measures every period: poll(now) calls measure(now) when due, `now` read
    # from the clock then.  A late poll skips the missed slots instead of bursting to catch up
    # (a stale burst measures nothing).
    # Its rate is a run-time key (`rate_hz`, up to MAX_RATE_HZ); a new rate takes effect at
    # once: the next measurement is at most one new period after the last one.
    # Aligned (board/timing.py): the measurements fall on the host-time grid of the period, so
    # every board with the same rate measures at the same instants; `phase` (a fraction of the
    # period) lets boards take turns.  Without a valid map of the host's clock it runs free, and
    # each such measurement is counted (timing.unaligned).
    MAX_RATE_HZ = 1000.0
    CONFIG = (("rate_hz", "float", (0.1, 1000.0), False),)
    # run-time keys that are the driver's attribute of the same name, read and set as they are
    PLAIN = ()
    ALIGNABLE = True
    # while not aligned, a measurement waits for room before the board's instants (pacing.py)
    PACED = True

    def __init__(self, clock, rate_hz):
        if not rate_hz > 0:
            raise ValueError("rate_hz must be > 0")
        self.clock = clock
        self.period_us = max(1, int(1000000 / rate_hz))
        self._due = None
        self._last = None
        self.aligned = False
        self.phase = 0.0
        self.timing = None  # set by the runtime's configuration when the board has timing
        self._free = True  # the next measurement was scheduled without the grid

    def realign(self):
        # alignment or phase changed: the next measurement is scheduled anew
        self._due = None

    def get_config(self, key):
        if key in self.PLAIN:
            return getattr(self, key)
        if key == "rate_hz":
            return round(1000000.0 / self.period_us, 3)
        raise ValueError("no key " + key)

    def set_config(self, key, value):
        if key in self.PLAIN:
            setattr(self, key, value)
            return
        if key != "rate_hz":
            raise ValueError("no key " + key)
        self.period_us = max(1, int(1000000 / value))
        if self.aligned:
            self._due = None  # the grid of the new period
        elif self._due is not None and self._last is not None:
            due = self._last + self.period_us
            if due < self._due:
                self._due = due

    def next_due_us(self):
        return self._due

    def poll(self, now, fresh=False):
        # Does nothing while `now` is before next_due_us() (pacing.py polls a paced driver only
        # when due); `fresh`: `now` is the clock just read (pacing's), not the loop's.
        if self._due is None:
            grid = self._grid(now)
            if grid is not None:
                self._due = grid  # wait for the grid's next instant
                return
            self._due = now
        if now < self._due:
            return
        # The loop's time is from before the drivers polled ahead of this one, which may have
        # held the loop (the HC-SR04 waits for its echo up to 33 ms): measure and reckon the
        # next slot from the clock now, or a slot that went by meanwhile is measured at once.
        if not fresh:
            now = self.clock()
        if self.aligned and self._free and self.timing is not None:
            self.timing.unaligned += 1  # measured now, but not on the grid: said
        grid = self._grid(now)
        if grid is None:
            self._due += self.period_us
            if self._due <= now:
                self._due = now + self.period_us
        else:
            self._due = grid
        self._last = now
        self.measure(now)

    def _grid(self, now):
        # the next grid instant (board µs) when aligned with a valid map, else None
        self._free = True
        if not self.aligned or self.timing is None:
            return None
        t = self.timing.next_grid(self.period_us, self.phase, now)
        if t is not None:
            self._free = False
        return t

    def measure(self, now):
        raise NotImplementedError


class Ranger(Periodic):
    # A single-beam ranger (HC-SR04, VL53L0X, SRF02, Sharp GP2Y0A02): one distance a
    # measurement, channel 0, a uint16_t in the part's unit; 0 is N/A (no echo, nothing in
    # range, too close).  The host publishes it as sensor_msgs/msg/Range (ros/standard/ranges.py
    # knows each part by its PREFIX).  A part says its PREFIX, MODEL and OPTIONS =
    # ranger_options(its unit[, min, max]): the limits where its descriptor states them.
    CHANNELS = 1
    DTYPE = "uint16_t"
    NA = 0


def ranger_options(unit, least=None, most=None):
    # A Ranger's descriptor options (least, most: its limits in `unit`, as the descriptor says
    # them).  Each a whole literal: MicroPython orders a dict's keys by its table, and a key added
    # later would reorder the descriptor's fields.
    ros = "sensor_msgs/msg/Range"
    if least is None:
        return {"unit": unit, "kind": "sensor", "ros": ros}
    return {"unit": unit, "kind": "sensor", "ros": ros, "min": least, "max": most}
