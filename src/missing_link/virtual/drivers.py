"""Simulated drivers: they follow the board rule (``set_cb``, then ``fn(channel, value)`` when a
value is new) and their signals are physically plausible and seeded, so runs repeat.  The
virtual boards (:mod:`.sims`, :mod:`.hostile`) are built from them."""

from __future__ import annotations

import math
import random
import struct
from collections.abc import Callable
from typing import Any

from ..board.runtime import BoardRuntime

ValueCb = Callable[[int, int | float | None], None]


def rng_for(seed: int, name: str) -> random.Random:
    """The random stream of one driver of one board: the same seed gives the same signal."""
    return random.Random(f"{seed}:{name}")


class _Driver:
    """Common driver plumbing: a callback, a period and the next due time (board µs); the rate
    is a run-time key (``rate_hz``, board/config.py) where the class lists it in CONFIG.

    ``ALIGNABLE`` drivers sample on the host-time grid when ``aligned`` (board/timing.py): at
    the grid's board tick, stamped with that tick, as a microcontroller whose timer triggers the
    measurement (the virtual board's process wakes up later than that, which the stamp does
    not show, as a timer-triggered ADC's would not).  Likewise what a timed call does (``a2jAt``)
    is stamped at the tick it was due at (``timing.acting_tick``), as a timer-compare output's
    edge would be, however late the process got round to the call."""

    period_us = 10_000
    CONFIG: tuple[tuple[str, str, tuple[float, float] | None, bool], ...] = ()
    ALIGNABLE = False

    def __init__(self, rng: random.Random) -> None:
        self.rng = rng
        self._cb: ValueCb | None = None
        self._due: int | None = None
        self._stamp: int | None = None  # the tick of the measurement under way, when aligned
        self.aligned = False
        self.phase = 0.0
        self.timing: Any = None  # set by the runtime's configuration (board/timing.py)
        self._free = True

    def realign(self) -> None:
        self._due = None

    def set_cb(self, fn: ValueCb) -> None:
        self._cb = fn

    def emit(self, channel: int, value: int | float | None) -> None:
        if self._cb is not None:
            stamp = self._stamp
            if stamp is None and self.timing is not None:
                stamp = self.timing.acting_tick  # (None unless a timed call is running)
            self._cb(channel, value, stamp)  # type: ignore[call-arg]

    def next_due_us(self) -> int | None:
        return self._due

    def get_config(self, key: str) -> float:
        if key != "rate_hz":
            raise ValueError(f"no key {key}")
        return round(1e6 / self.period_us, 3)

    def set_config(self, key: str, value: float) -> None:
        if key != "rate_hz":
            raise ValueError(f"no key {key}")
        old, self.period_us = self.period_us, max(1, round(1e6 / value))
        if self.aligned:
            self._due = None  # the grid of the new period
        elif self._due is not None:  # the next sample one new period after the last at most
            self._due = min(self._due, self._due - old + self.period_us)

    def _grid(self, now: int) -> int | None:
        self._free = True
        if not self.aligned or self.timing is None:
            return None
        t: int | None = self.timing.next_grid(self.period_us, self.phase, now)
        self._free = t is None
        return t

    def poll(self, now: int) -> None:
        if self._due is None:
            # On the grid when aligned; else a random phase, so drivers do not all fire at once.
            grid = self._grid(now)
            self._due = grid if grid is not None else now + self.rng.randrange(self.period_us)
            return
        if now < self._due:
            return
        scheduled = self._due
        if self.aligned and self._free and self.timing is not None:
            self.timing.unaligned += 1  # not on the grid (no valid map): said
        self._stamp = scheduled if self.aligned else None
        try:
            self.step(now)
        finally:
            self._stamp = None
        grid = self._grid(now)
        if grid is not None:
            self._due = grid
            return
        self._due += self.period_us
        if self._due < now:  # fell behind (e.g. the process was paused): skip, do not burst
            self._due = now + self.period_us

    def step(self, now: int) -> None:
        raise NotImplementedError


class QuadEncoders(_Driver):
    """Two HEDS-6500 wheel encoders (500 CPR, x4 decoding = 2000 counts/rev) on a robot that
    accelerates and turns smoothly.  Counts wrap like the int16 hardware counter; a channel is
    reported only when its count changed (polled at 1 kHz)."""

    period_us = 1_000
    COUNTS_PER_REV = 2000

    def __init__(self, rng: random.Random) -> None:
        super().__init__(rng)
        self.speed = [0.0, 0.0]  # rev/s
        self.target = [0.0, 0.0]
        self.pos = [0.0, 0.0]  # counts, unwrapped
        self.sent = [None, None]  # type: list[int | None]
        self._retarget = 0

    def step(self, now: int) -> None:
        dt = self.period_us / 1e6
        if now >= self._retarget:
            base = self.rng.uniform(-1.5, 1.5)
            turn = self.rng.uniform(-0.4, 0.4)
            self.target = [base - turn, base + turn]
            self._retarget = now + self.rng.randrange(1_000_000, 3_000_000)
        for ch in (0, 1):
            # First-order response of a wheel motor, time constant 0.3 s.
            self.speed[ch] += (self.target[ch] - self.speed[ch]) * dt / 0.3
            self.pos[ch] += self.speed[ch] * dt * self.COUNTS_PER_REV
            count = ((int(self.pos[ch]) + 32768) & 0xFFFF) - 32768
            if count != self.sent[ch]:
                self.sent[ch] = count
                self.emit(ch, count)


class SharpIR(_Driver):
    """Eight GP2Y0A02YK rangers (200..1500 mm) read by the ADC at ~25 Hz as one sweep.
    Out-of-range readings are not a number: they become N/A."""

    period_us = 40_000
    CONFIG = (("rate_hz", "float", (0.1, 26.0), False),)  # the sensor updates every 38 ms
    ALIGNABLE = True

    def __init__(self, rng: random.Random, channels: int = 8) -> None:
        super().__init__(rng)
        self.channels = channels
        self.dist = [rng.uniform(300, 1400) for _ in range(channels)]
        self.vel = [0.0] * channels

    def step(self, now: int) -> None:
        dt = self.period_us / 1e6
        for ch in range(self.channels):
            # Obstacles drift (random-walk velocity, mm/s) and bounce inside 100..1700 mm.
            self.vel[ch] = 0.95 * self.vel[ch] + self.rng.gauss(0, 40)
            self.dist[ch] += self.vel[ch] * dt
            if not 100 <= self.dist[ch] <= 1700:
                self.vel[ch] = -self.vel[ch]
                self.dist[ch] = min(max(self.dist[ch], 100), 1700)
            reading = self.dist[ch] * (1 + self.rng.gauss(0, 0.01))
            if 200 <= reading <= 1500:
                self.emit(ch, round(reading))
            else:
                self.emit(ch, -1)  # illegal for uint16: the runtime sends N/A


class SRF02Sonars(_Driver):
    """Twelve SRF02 sonars (150..6000 mm).  They must not ping together (cross-talk), so they
    fire in three groups of four; each sonar updates at ~25 Hz."""

    period_us = 13_333
    GROUPS = 3
    #: each sonar's rate: a group fires every period, so one sonar every GROUPS periods; how
    #: many groups take turns is the wiring's (read-only)
    CONFIG = (("rate_hz", "float", (0.1, 30.0), False), ("groups", "int", (1, 12), True))

    def get_config(self, key: str) -> float:
        if key == "groups":
            return self.GROUPS
        return round(super().get_config(key) / self.GROUPS, 3)

    def set_config(self, key: str, value: float) -> None:
        super().set_config(key, value * self.GROUPS)

    def __init__(self, rng: random.Random, channels: int = 12) -> None:
        super().__init__(rng)
        self.channels = channels
        self.group = 0
        self.room = [rng.uniform(500, 5000) for _ in range(channels)]

    def step(self, now: int) -> None:
        per = self.channels // self.GROUPS
        for ch in range(self.group * per, (self.group + 1) * per):
            self.room[ch] += self.rng.gauss(0, 15)
            self.room[ch] = min(max(self.room[ch], 100), 6500)
            echo = self.room[ch] + self.rng.gauss(0, 10)
            if self.rng.random() < 0.01 or not 150 <= echo <= 6000:
                self.emit(ch, 0x00FFFFFF)  # no echo: N/A
            else:
                self.emit(ch, round(echo))
        self.group = (self.group + 1) % self.GROUPS


class Servo(_Driver):
    """An HS-645MG servo: commanded in -127..127 (int8 = -90..+90 degrees), moving at its rated
    0.24 s / 60 degrees; reports its position at 50 Hz while moving and on every command."""

    period_us = 20_000
    DEG_PER_S = 60 / 0.24
    #: the horn's travel, in degrees: a command beyond is held at the limit; ``safe``: what the
    #: failsafe does (board/failsafe.py): hold where it is, or go limp (reported as N/A)
    CONFIG: tuple[tuple[str, str, Any, bool], ...] = (
        ("min_deg", "int", (-90, 90), False),
        ("max_deg", "int", (-90, 90), False),
        ("safe", "enum", ("hold", "limp"), False),
    )

    def __init__(self, rng: random.Random) -> None:
        super().__init__(rng)
        self.position = 0.0  # degrees
        self.target = 0.0
        self.commands = 0
        self.limits = {"min_deg": -90, "max_deg": 90}
        self.safe = "hold"
        self.limp = False

    def get_config(self, key: str) -> Any:
        return self.safe if key == "safe" else self.limits[key]

    def set_config(self, key: str, value: Any) -> None:
        if key == "safe":
            self.safe = str(value)
        else:
            self.limits[key] = int(value)

    def make_safe(self) -> None:
        """The failsafe, as the firmware's servo (board/drivers/servo.py, AVR drivers.c): hold
        keeps the last pulse (the horn goes on to the last command and stays there), limp stops
        the pulses (the horn stays where it is, reported as N/A).  Nothing is reset, so what a
        late command did after the host had gone shows here as on the firmware."""
        self.limp = self.safe == "limp"
        self.emit(0, None if self.limp else self.reported())

    def check_config(self) -> str | None:
        lo, hi = self.limits["min_deg"], self.limits["max_deg"]
        if lo >= hi:
            return f"need min_deg < max_deg ({lo}, {hi})"
        self.target = min(max(self.target, lo), hi)
        return None

    def command(self, payload: bytes) -> tuple[int, bytes]:
        if len(payload) != 1:
            return 0xFF, b"expects one int8"
        (value,) = struct.unpack("<b", payload)
        if value == -128:
            return 0xFF, b"-128 is N/A"
        self.target = min(max(value * 90 / 127, self.limits["min_deg"]), self.limits["max_deg"])
        self.limp = False
        self.commands += 1
        self.emit(0, self.reported())
        return 0, b""

    def reported(self) -> int:
        return max(-127, min(127, round(self.position * 127 / 90)))

    def step(self, now: int) -> None:
        if self.position == self.target or self.limp:
            return
        step = self.DEG_PER_S * self.period_us / 1e6
        delta = self.target - self.position
        self.position = (
            self.target if abs(delta) <= step else self.position + math.copysign(step, delta)
        )
        self.emit(0, self.reported())


class Trigger(_Driver):
    """``setTrigger(u64 board µs)``: at that board time the board toggles a (virtual) pin and
    reports the moment it fired as a sample - the two-board synchronised-action experiment."""

    def __init__(self, rng: random.Random) -> None:
        super().__init__(rng)
        self.at: int | None = None
        self.fired = 0

    def next_due_us(self) -> int | None:
        return self.at

    def set(self, payload: bytes) -> tuple[int, bytes]:
        if len(payload) != 8:
            return 0xFF, b"expects u64 board microseconds"
        (self.at,) = struct.unpack("<Q", payload)
        return 0, b""

    def set_at_host(self, rt: BoardRuntime) -> Callable[[bytes], tuple[int, bytes]]:
        """``setTriggerAt(i64 host ns)``: the same, at a host time, through the host's map
        (``a2jHostMap``): the board converts it to its own tick."""

        def handler(payload: bytes) -> tuple[int, bytes]:
            if len(payload) != 8:
                return 0xFF, b"expects i64 host nanoseconds"
            at = rt.board_time_at(struct.unpack("<q", payload)[0])
            if at is None:
                return 0xFF, b"no host map yet (a2jHostMap)"
            self.at = at
            return 0, struct.pack("<Q", at)

        return handler

    def poll(self, now: int) -> None:
        if self.at is not None and now >= self.at:
            self.at = None
            self.fired += 1
            self.emit(0, self.fired & 0xFF)


class PulseTrigger(_Driver):
    """A trigger output (a camera's or a scope's): ``a2j_trigger`` (u16 width in µs; 0 = the
    configured ``pulse_us``) makes one pulse, reported as a sample of its width stamped at its
    rising edge.  Through ``a2jAt`` (board/timing.py) it fires at a host time, stamped at the
    tick the call was due at (see _Driver)."""

    CONFIG = (("pulse_us", "int", (1, 65535), False),)

    def __init__(self, rng: random.Random, pulse_us: int = 10) -> None:
        super().__init__(rng)
        self.pulse_us = pulse_us
        self.fired = 0

    def get_config(self, key: str) -> float:
        return self.pulse_us

    def set_config(self, key: str, value: float) -> None:
        self.pulse_us = int(value)

    def next_due_us(self) -> int | None:
        return None

    def poll(self, now: int) -> None:
        pass

    def command(self, payload: bytes) -> tuple[int, bytes]:
        if len(payload) != 2:
            return 0xFF, b"expects u16 width in us"
        width = struct.unpack("<H", payload)[0] or self.pulse_us
        self.fired += 1
        self.emit(0, width)
        return 0, b""


class Counter(_Driver):
    """A test signal at an exact rate: every channel gets the sample counter (benchmarks)."""

    CONFIG = (("rate_hz", "float", (0.1, 100000.0), False),)
    ALIGNABLE = True

    def __init__(self, rng: random.Random, rate_hz: float, channels: int) -> None:
        super().__init__(rng)
        self.period_us = max(1, round(1e6 / rate_hz))
        self.channels = channels
        self.n = 0

    def step(self, now: int) -> None:
        self.n += 1
        for ch in range(self.channels):
            self.emit(ch, self.n & 0x7FFFFFFF)
