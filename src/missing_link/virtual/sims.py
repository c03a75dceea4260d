"""Simulated boards.  Drivers follow the board rule (``set_cb``, ``fn(channel, value)``) and the
signals are physically plausible and seeded, so runs repeat.

``thesis``: the thesis's board (Listing 9.2) - two quadrature wheel encoders, 8 Sharp IR rangers,
12 SRF02 sonars, an HS-645MG servo actuator, ``getTime`` and ``setTrigger``.
``encoder_servo`` / ``rangers``: the same hardware split over two boards (the demo rig).
``original``: a Part 1 board as the 2014 firmware builds it (the golden-vector function table).
The hostile and buggy boards of :mod:`.hostile` are here too, by name (``hostile_*``).
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import Any

from ..board.config import RuntimeConfig
from ..board.failsafe import Failsafe
from ..board.runtime import BoardRuntime, Transducer
from ..board.store import FileStore
from ..board.timing import Timing
from .drivers import (
    Counter,
    PulseTrigger,
    QuadEncoders,
    Servo,
    SharpIR,
    SRF02Sonars,
    Trigger,
    rng_for,
)
from .hostile import HOSTILE
from .original import OriginalRuntime


def _common(rt: BoardRuntime, seed: int) -> None:
    rt.add_function("getTime", lambda p: (0, struct.pack("<Q", rt.clock())))
    trig = Trigger(rng_for(seed, "trigger"))
    rt.add_function("setTrigger", trig.set)
    rt.add_function("setTriggerAt", trig.set_at_host(rt))
    rt.add_transducer(Transducer("trigger", 4, "gpio", "GPIO-OUT", 1, "uint8_t", 0), trig)


def _add_encoders(rt: BoardRuntime, seed: int) -> None:
    # (500 CPR with x4 decoding: QuadEncoders)
    quad = Transducer("quad", 0, "quad", "HEDS-6500", 2, "int16_t", -1, unit="count",
                      kind="sensor", counts_per_rev="2000")  # fmt: skip
    rt.add_transducer(quad, QuadEncoders(rng_for(seed, "quad")))


def _add_servo(rt: BoardRuntime, seed: int) -> Servo:
    servo = Servo(rng_for(seed, "servo"))
    t = Transducer(
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
    )
    rt.add_function("a2j_set_servo", rt.gated(t, servo.command))
    rt.add_transducer(t, servo)
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
        SharpIR(rng_for(seed, "ir")),
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
        SRF02Sonars(rng_for(seed, "us")),
    )


def _configurable(rt: BoardRuntime, config_file: str | None) -> BoardRuntime:
    """Acting on host time (board/timing.py: aligned sampling, timed calls) and the run-time
    configuration (board/config.py), saved to ``config_file`` if given (else the board has no
    storage: a save is refused, saying so)."""
    rt.timing = Timing(rt)
    rt.failsafe = Failsafe(rt)  # actuators made safe when the host is gone
    rt.config = RuntimeConfig(rt, FileStore(config_file) if config_file else None)
    rt.add_function("a2jLogInfo", rt.log.info)  # the log's counts (board/log.py), as firmware's
    return rt


def _rig(
    kind: str, parts: tuple[Callable[[BoardRuntime, int], object], ...], seed: int, name: str,
    config_file: str | None, kw: dict[str, Any],
) -> BoardRuntime:  # fmt: skip
    """A virtual rig: ``parts`` added in order, then what every rig has."""
    rt = BoardRuntime(name, f"missing-link virtual {kind} board", f"sim-{name}-{seed}", **kw)
    for add in parts:
        add(rt, seed)
    _common(rt, seed)
    return _configurable(rt, config_file)


def thesis(
    seed: int = 0, name: str = "thesis", config_file: str | None = None, **kw: Any
) -> BoardRuntime:
    return _rig("thesis", (_add_encoders, _add_rangers, _add_servo), seed, name, config_file, kw)


def encoder_servo(
    seed: int = 0, name: str = "board_a", config_file: str | None = None, **kw: Any
) -> BoardRuntime:
    return _rig("encoder+servo", (_add_encoders, _add_servo), seed, name, config_file, kw)


def rangers(
    seed: int = 0, name: str = "board_b", config_file: str | None = None, **kw: Any
) -> BoardRuntime:
    return _rig("ranger", (_add_rangers,), seed, name, config_file, kw)


def rate(
    seed: int = 0,
    name: str = "rate",
    rate_hz: float = 100.0,
    channels: int = 1,
    config_file: str | None = None,
    **kw: object,
) -> BoardRuntime:
    """One transducer ``signal`` (int32 counter) at ``rate_hz`` updates/s: for benchmarks."""
    rt = BoardRuntime(name, "missing-link rate generator", f"sim-{name}-{seed}", **kw)
    rt.add_transducer(
        Transducer("signal", 0, "counter", "COUNTER", channels, "int32_t", -1, rate_hz=rate_hz),
        Counter(rng_for(seed, "counter"), rate_hz, channels),
    )
    return _configurable(rt, config_file)


def aligned(
    seed: int = 0,
    name: str = "aligned",
    rate_hz: float = 50.0,
    config_file: str | None = None,
    **kw: object,
) -> BoardRuntime:
    """Measuring together, acting on time (bench/bench_aligned.py): ``signal`` (a counter at
    ``rate_hz``, alignable to the host-time grid) and ``trigger`` (a pulse output, an actuator
    that takes timed commands)."""
    rt = BoardRuntime(name, "missing-link aligned sampling board", f"sim-{name}-{seed}", **kw)
    rt.add_transducer(
        Transducer("signal", 0, "counter", "COUNTER", 1, "int32_t", -1, rate_hz=rate_hz),
        Counter(rng_for(seed, "counter"), rate_hz, 1),
    )
    trig = PulseTrigger(rng_for(seed, "trigger"))
    t = Transducer(
        "trigger", 1, "gpio", "PULSE", 1, "uint16_t", 0, unit="us", kind="actuator",
        call="a2j_trigger",
    )  # fmt: skip
    rt.add_function("a2j_trigger", rt.gated(t, trig.command))
    rt.add_transducer(t, trig)
    return _configurable(rt, config_file)


def original(seed: int = 0, name: str = "original", **kw: object) -> BoardRuntime:
    """A Part 1 board: the golden-vector table, no Part 2 functions, no j2a.version, and the
    2014 firmware's a2jMany (its offset bug)."""
    rt = OriginalRuntime(name, "2014 firmware (emulated)", f"sim-{name}-{seed}", part2=False, **kw)
    rt.add_function("getTime", lambda p: (0, struct.pack("<Q", rt.clock())))
    rt.add_function("syncTime", lambda p: (0, b""))
    blob = bytes(rng_for(seed, "blob").randrange(256) for _ in range(1000))
    rt.add_blob_function("bigBlob", lambda: blob)
    # Sample SIFs like the thesis firmware: cmd 13, [u64 µs][i16]
    rt.add_transducer(
        Transducer("quad", 13, "quad", "HEDS-6500", 1, "int16_t", -1), _OneEncoder(seed)
    )
    return rt


class _OneEncoder(QuadEncoders):
    def __init__(self, seed: int) -> None:
        super().__init__(rng_for(seed, "quad1"))

    def emit(self, channel: int, value: int | float | None) -> None:
        if channel == 0:
            super().emit(0, value)


SIMS: dict[str, Callable[..., BoardRuntime]] = {
    "thesis": thesis,
    "encoder_servo": encoder_servo,
    "rangers": rangers,
    "original": original,
    "rate": rate,
    "aligned": aligned,
}

SIMS.update(HOSTILE)


def make_sim(sim: str, seed: int = 0, **kw: object) -> BoardRuntime:
    """A simulated board runtime; ``kw`` go to the sim (e.g. ``name`` = board.name)."""
    try:
        factory = SIMS[sim]
    except KeyError:
        raise ValueError(f"unknown sim {sim!r}; choose one of {', '.join(SIMS)}") from None
    return factory(seed=seed, **kw)
