"""Simulated boards.  Drivers follow the board rule (``set_cb``, ``fn(channel, value)``) and the
signals are physically plausible and seeded, so runs repeat.

``thesis``: the thesis's board (Listing 9.2) - two quadrature wheel encoders, 8 Sharp IR rangers,
12 SRF02 sonars, an HS-645MG servo actuator, ``getTime`` and ``setTrigger``.
``encoder_servo`` / ``rangers``: the same hardware split over two boards (the demo rig).
``original``: a Part 1 board as the 2014 firmware builds it (the golden-vector function table).
"""

from __future__ import annotations

import math
import random
import struct
import time
from collections.abc import Callable

from ..board.runtime import BoardRuntime, Transducer

ValueCb = Callable[[int, int | float], None]


class AffineClock:
    """A board clock whose truth is known: board µs = offset + (1 + skew) * host monotonic µs.

    Benchmarks and tests give a virtual board this clock (``missing-link board --clock-offset-us
    --clock-skew-ppm``) and compare the daemon's host times with :meth:`host_ns`."""

    def __init__(self, offset_us: float, skew_ppm: float) -> None:
        self.offset_us = offset_us
        self.rate = 1.0 + skew_ppm * 1e-6

    def __call__(self) -> int:
        return math.floor(self.offset_us + time.monotonic_ns() * self.rate / 1000.0)

    def host_ns(self, board_us: float) -> float:
        """The CLOCK_MONOTONIC ns at which this clock read ``board_us``."""
        return (board_us - self.offset_us) * 1000.0 / self.rate


class DriftClock:
    """A board clock with offset, skew, a linear drift of the skew, and resets, whose truth is
    known to any process that knows its parameters (the benchmarks' independent check).

    With ``d`` = host µs since ``ref_ns`` (host CLOCK_MONOTONIC), the clock runs at
    ``1 + (skew_ppm + drift_ppm_per_s * d / 1e6) * 1e-6`` board µs per host µs.  Boot 0 starts
    at ``offset_us``; at each ``resets`` time (s after ``ref_ns``) the board resets: its counter
    restarts at 0 at that instant (the boot gap is the server's business: see BoardServer)."""

    def __init__(
        self,
        offset_us: float,
        skew_ppm: float,
        drift_ppm_per_s: float = 0.0,
        ref_ns: int | None = None,
        resets: list[float] | None = None,
    ) -> None:
        self.offset_us = offset_us
        self.skew = skew_ppm * 1e-6
        self.drift = drift_ppm_per_s * 1e-12  # per µs of elapsed time, per µs
        self.ref_ns = time.monotonic_ns() if ref_ns is None else ref_ns
        self.reset_ns = [self.ref_ns + round(s * 1e9) for s in sorted(resets or [])]

    def _f(self, host_ns: float) -> float:
        d = (host_ns - self.ref_ns) / 1000.0
        return d * (1.0 + self.skew) + self.drift * d * d / 2.0

    def boot_at(self, host_ns: float) -> int:
        return sum(1 for r in self.reset_ns if r <= host_ns)

    def _start(self, boot: int) -> tuple[float, float]:
        """(host ns, board µs) where boot ``boot`` starts."""
        if boot == 0:
            return float(self.ref_ns), self.offset_us
        return float(self.reset_ns[boot - 1]), 0.0

    def board_us_at(self, host_ns: float) -> float:
        h0, b0 = self._start(self.boot_at(host_ns))
        return b0 + self._f(host_ns) - self._f(h0)

    def __call__(self) -> int:
        return math.floor(self.board_us_at(time.monotonic_ns()))

    def host_ns(self, board_us: float, boot: int = 0) -> float:
        """The CLOCK_MONOTONIC ns at which boot ``boot`` of this clock read ``board_us``."""
        h0, b0 = self._start(boot)
        h = h0 + (board_us - b0) * 1000.0  # Newton from the nominal rate
        for _ in range(4):
            err = b0 + self._f(h) - self._f(h0) - board_us
            rate = 1.0 + self.skew + self.drift * (h - self.ref_ns) / 1000.0
            h -= err * 1000.0 / rate
        return h


class _Driver:
    """Common driver plumbing: a callback, a period and the next due time (board µs)."""

    period_us = 10_000

    def __init__(self, rng: random.Random) -> None:
        self.rng = rng
        self._cb: ValueCb | None = None
        self._due: int | None = None

    def set_cb(self, fn: ValueCb) -> None:
        self._cb = fn

    def emit(self, channel: int, value: int | float) -> None:
        if self._cb is not None:
            self._cb(channel, value)

    def next_due_us(self) -> int | None:
        return self._due

    def poll(self, now: int) -> None:
        if self._due is None:
            # Random phase so that drivers do not all fire at once.
            self._due = now + self.rng.randrange(self.period_us)
            return
        if now < self._due:
            return
        self.step(now)
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

    def __init__(self, rng: random.Random) -> None:
        super().__init__(rng)
        self.position = 0.0  # degrees
        self.target = 0.0
        self.commands = 0

    def command(self, payload: bytes) -> tuple[int, bytes]:
        if len(payload) != 1:
            return 0xFF, b"expects one int8"
        (value,) = struct.unpack("<b", payload)
        if value == -128:
            return 0xFF, b"-128 is N/A"
        self.target = value * 90 / 127
        self.commands += 1
        self.emit(0, self.reported())
        return 0, b""

    def reported(self) -> int:
        return max(-127, min(127, round(self.position * 127 / 90)))

    def step(self, now: int) -> None:
        if self.position == self.target:
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


class Counter(_Driver):
    """A test signal at an exact rate: every channel gets the sample counter (benchmarks)."""

    def __init__(self, rng: random.Random, rate_hz: float, channels: int) -> None:
        super().__init__(rng)
        self.period_us = max(1, round(1e6 / rate_hz))
        self.channels = channels
        self.n = 0

    def step(self, now: int) -> None:
        self.n += 1
        for ch in range(self.channels):
            self.emit(ch, self.n & 0x7FFFFFFF)


def _rng(seed: int, name: str) -> random.Random:
    return random.Random(f"{seed}:{name}")


def _common(rt: BoardRuntime, seed: int) -> None:
    rt.add_function("getTime", lambda p: (0, struct.pack("<Q", rt.clock())))
    trig = Trigger(_rng(seed, "trigger"))
    rt.add_function("setTrigger", trig.set)
    rt.add_function("setTriggerAt", trig.set_at_host(rt))
    rt.add_transducer(Transducer("trigger", 4, "gpio", "GPIO-OUT", 1, "uint8_t", 0), trig)


def _add_encoders(rt: BoardRuntime, seed: int) -> None:
    rt.add_transducer(
        Transducer("quad", 0, "quad", "HEDS-6500", 2, "int16_t", -1, unit="count", kind="sensor"),
        QuadEncoders(_rng(seed, "quad")),
    )


def _add_servo(rt: BoardRuntime, seed: int) -> Servo:
    servo = Servo(_rng(seed, "servo"))
    rt.add_function("a2j_set_servo", servo.command)
    rt.add_transducer(
        Transducer(
            "servo",
            3,
            "hs645",
            "HS-645MG",
            1,
            "int8_t",
            -128,
            kind="actuator",
            call="a2j_set_servo",
            unit="deg",
            scale="0.708661",  # int8 command -127..127 = -90..+90 degrees
            ros="sensor_msgs/msg/JointState",
        ),
        servo,
    )
    return servo


def _add_rangers(rt: BoardRuntime, seed: int) -> None:
    rt.add_transducer(
        Transducer(
            "dist_ir",
            1,
            "sharp",
            "GP2Y0A02YK",
            8,
            "uint16_t",
            0,
            unit="mm",
            rate_hz=25,
            min=200,
            max=1500,
            ros="sensor_msgs/msg/Range",
        ),
        SharpIR(_rng(seed, "ir")),
    )
    rt.add_transducer(
        Transducer(
            "dist_us",
            2,
            "srf02",
            "SRF02",
            12,
            "uint32_t",
            0x00FFFFFF,
            unit="mm",
            rate_hz=25,
            min=150,
            max=6000,
            ros="sensor_msgs/msg/Range",
        ),
        SRF02Sonars(_rng(seed, "us")),
    )


def thesis(seed: int = 0, name: str = "thesis", **kw: object) -> BoardRuntime:
    rt = BoardRuntime(name, "missing-link virtual thesis board", f"sim-{name}-{seed}", **kw)
    _add_encoders(rt, seed)
    _add_rangers(rt, seed)
    _add_servo(rt, seed)
    _common(rt, seed)
    return rt


def encoder_servo(seed: int = 0, name: str = "board_a", **kw: object) -> BoardRuntime:
    rt = BoardRuntime(name, "missing-link virtual encoder+servo board", f"sim-{name}-{seed}", **kw)
    _add_encoders(rt, seed)
    _add_servo(rt, seed)
    _common(rt, seed)
    return rt


def rangers(seed: int = 0, name: str = "board_b", **kw: object) -> BoardRuntime:
    rt = BoardRuntime(name, "missing-link virtual ranger board", f"sim-{name}-{seed}", **kw)
    _add_rangers(rt, seed)
    _common(rt, seed)
    return rt


def rate(
    seed: int = 0, name: str = "rate", rate_hz: float = 100.0, channels: int = 1, **kw: object
) -> BoardRuntime:
    """One transducer ``signal`` (int32 counter) at ``rate_hz`` updates/s: for benchmarks."""
    rt = BoardRuntime(name, "missing-link rate generator", f"sim-{name}-{seed}", **kw)
    rt.add_transducer(
        Transducer("signal", 0, "counter", "COUNTER", channels, "int32_t", -1, rate_hz=rate_hz),
        Counter(_rng(seed, "counter"), rate_hz, channels),
    )
    return rt


def original(seed: int = 0, name: str = "original", **kw: object) -> BoardRuntime:
    """A Part 1 board: the golden-vector table, no Part 2 functions, no j2a.version."""
    rt = BoardRuntime(name, "2014 firmware (emulated)", f"sim-{name}-{seed}", part2=False, **kw)
    rt.add_function("getTime", lambda p: (0, struct.pack("<Q", rt.clock())))
    rt.add_function("syncTime", lambda p: (0, b""))
    blob = bytes(_rng(seed, "blob").randrange(256) for _ in range(1000))
    rt.add_blob_function("bigBlob", lambda: blob)
    # Sample SIFs like the thesis firmware: cmd 13, [u64 µs][i16]
    rt.add_transducer(
        Transducer("quad", 13, "quad", "HEDS-6500", 1, "int16_t", -1), _OneEncoder(seed)
    )
    return rt


class _OneEncoder(QuadEncoders):
    def __init__(self, seed: int) -> None:
        super().__init__(_rng(seed, "quad1"))

    def emit(self, channel: int, value: int | float) -> None:
        if channel == 0:
            super().emit(0, value)


SIMS: dict[str, Callable[..., BoardRuntime]] = {
    "thesis": thesis,
    "encoder_servo": encoder_servo,
    "rangers": rangers,
    "original": original,
    "rate": rate,
}


def _add_hostile() -> None:
    from .hostile import HOSTILE  # hostile boards build on the drivers above

    SIMS.update(HOSTILE)


_add_hostile()


def make_sim(sim: str, seed: int = 0, **kw: object) -> BoardRuntime:
    """A simulated board runtime; ``kw`` go to the sim (e.g. ``name`` = board.name)."""
    try:
        factory = SIMS[sim]
    except KeyError:
        raise ValueError(f"unknown sim {sim!r}; choose one of {', '.join(SIMS)}") from None
    return factory(seed=seed, **kw)
