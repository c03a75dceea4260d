"""Will a board file's MicroPython firmware fit its board's heap?  (``flash`` asks before it
copies anything; docs/hardware.md, "Memory".)

The estimate is a sum of figures measured in the simulator (the firmware in MicroPython's
WebAssembly port, 32-bit like a board: ``virtual/world/heapprobe.mjs``, live heap after a
collection): the firmware's own modules and an empty firmware (RUNTIME), each driver module a
board file uses (MODULES), each transducer (INSTANCES, by driver), each I2C bus (BUS), and the
room the firmware needs beyond its live data (WORKING: the garbage between its collections,
a module's compilation at boot, a driver's start-up).  WORKING was measured as the smallest
``--heap`` under which the thesis rig (examples/boards/thesis-rig.py) runs 20 simulated seconds
with a host (a bisection: ``smallest_heap`` in tests/memory_soak.py), less its live data.  The
simulator is stricter than a board (it collects only between steps, a board while it
allocates): the rover needed about 80 KiB beyond its live data there, for its VL53L0X's calibration,
which polls the part in a loop within one step whose garbage a board collects as it goes.
It is compared with what the board's MicroPython has free after it boots (FREE_HEAP, by
``mcu``, with where the figure comes from).
"""

from __future__ import annotations

import json
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..board.drivers import DRIVERS
from ..errors import ConfigError
from .boardfile import BoardFile

KIB = 1024


@dataclass(frozen=True)
class FreeHeap:
    bytes: int
    cite: str  #: where the figure is from, short (the message names it)
    source: str  #: ... and what it is


#: gc.mem_free() after MicroPython boots, by the board file's ``mcu``
FREE_HEAP = {
    "rp2040": FreeHeap(
        209_936,
        "micropython/micropython#12557",
        "a Raspberry Pi Pico's gc.mem_free() right after boot, MicroPython 1.20 "
        "(micropython/micropython#12557); the RP2040 port's heap is the RAM its linker script "
        "leaves (ports/rp2/memmap_mp_rp2040.ld, __GcHeapStart to the end of RAM)",
    ),
    "esp32": FreeHeap(
        110_368,
        "micropython/micropython#13219",
        "an ESP32's (no PSRAM) heap once grown, 111,936 bytes since MicroPython 1.22 "
        "(micropython/micropython#13219: the heap starts smaller and grows on demand, once to "
        "that), less the 1,568 bytes used at boot (micropython/micropython#12141); before 1.21 "
        "gc.mem_free() said 91,088 after boot (micropython/micropython#7043)",
    ),
    "esp32s3": FreeHeap(
        250_784,
        "micropython/micropython#12141",
        "an ESP32-S3's free heap plus the 'max new split' it may add, from micropython.mem_info()"
        " after boot (micropython/micropython#12141: 62,432 + 188,352)",
    ),
}

#: the firmware's modules and a firmware with no transducers (bytes, live)
RUNTIME = 58_064
#: an I2C bus
BUS = 64
#: a driver module, imported once (by module: two drivers may share one)
MODULES = {
    "encoder": 1_648, "sharp": 1_760, "srf02": 2_272, "servo": 2_208, "digital": 1_840,
    "analog": 864, "mpu6050": 2_112, "trigger": 1_216, "gps_nmea": 3_808, "compass": 3_664,
    "hbridge": 2_768, "stepper": 3_408, "hcsr04": 1_560, "vl53l0x": 2_976, "battery": 3_904,
}  # fmt: skip
#: a transducer, by driver
INSTANCES = {
    "quadrature": 1_872, "sharp_gp2y0a02": 1_568, "srf02": 2_272, "servo": 2_656, "digital": 1_280,
    "analog": 1_984, "mpu6050": 2_608, "trigger": 1_136, "gps_nmea": 672, "hmc5883l": 1_936,
    "qmc5883l": 1_936, "hbridge": 2_016, "stepper": 2_400, "hcsr04": 2_144, "vl53l0x": 2_000,
    "battery": 2_512,
}  # fmt: skip
#: a network link with a key (signing.py): its module and state
SIGNED_LINK = 4_864
#: room beyond the live data: the thesis rig ran from 108,026 bytes with 80,432 live (20 s, a
#: host; the bisection above), and from 115,625 once the board log, identity and updates had
#: joined the runtime (the rover from 194,321, in the simulator)
WORKING = 28 * KIB

#: what heapprobe.mjs builds, one of each driver (and two, for a transducer's share)
PROBE_BUS = {"id": 0, "scl": 5, "sda": 4, "freq": 400000}
PROBE_ENTRIES: dict[str, dict[str, Any]] = {
    "quadrature": {"pin_a": 2, "pin_b": 3, "rate_hz": 50},
    "sharp_gp2y0a02": {"pin": 26, "rate_hz": 25},
    "srf02": {"bus": "i2c0", "rate_hz": 10},
    "servo": {"pin": 15},
    "digital": {"pin": 14, "debounce_ms": 20},
    "analog": {"pin": 27},
    "mpu6050": {"bus": "i2c0", "rate_hz": 100},
    "trigger": {"pin": 16, "pulse_us": 100},
    "gps_nmea": {"uart": 1, "tx": 8, "rx": 9, "baud": 9600, "pps_pin": 10},
    "hmc5883l": {"bus": "i2c0", "rate_hz": 15},
    "qmc5883l": {"bus": "i2c0", "rate_hz": 50},
    "hbridge": {"in1": 12, "in2": 13},
    "stepper": {"step_pin": 20, "dir_pin": 21, "enable_pin": 22},
    "hcsr04": {"trig_pin": 17, "echo_pin": 18, "rate_hz": 10},
    "vl53l0x": {"bus": "i2c0", "rate_hz": 10},
    "battery": {"pin": 28},
}


class DoesNotFit(ConfigError):
    """A board file whose firmware needs more memory than its board has."""


@dataclass(frozen=True)
class Estimate:
    need: int  #: bytes of heap
    parts: tuple[tuple[str, int], ...]  #: (what, bytes), biggest first


def estimate(bf: BoardFile) -> Estimate:
    """The heap ``bf``'s MicroPython firmware needs (bytes), and what it is made of."""
    parts: dict[str, int] = {"the firmware's runtime": RUNTIME, "working room": WORKING}
    count: dict[str, int] = {}
    for t in bf.transducers:
        count[t["driver"]] = count.get(t["driver"], 0) + 1
    for driver, n in count.items():
        parts[f"{n} x {driver}"] = n * INSTANCES[driver]
    for module in sorted({DRIVERS[d][0] for d in count}):
        parts[f"module {module}"] = MODULES[module]
    if bf.board.get("link", {}).get("key_file"):
        parts["signed network link"] = SIGNED_LINK
    buses = len(bf.board.get("buses", {}))
    if buses:
        parts[f"{buses} I2C bus{'es' if buses > 1 else ''}"] = buses * BUS
    ranked = tuple(sorted(parts.items(), key=lambda kv: -kv[1]))
    return Estimate(sum(parts.values()), ranked)


def check_fit(bf: BoardFile) -> Estimate | None:
    """The estimate, or DoesNotFit (one line: the numbers, the biggest consumers, the figure's
    source) when it is over what ``bf``'s mcu has free; None for a board that is no
    MicroPython board with a known figure."""
    free = FREE_HEAP.get(bf.mcu)
    if free is None:
        return None
    est = estimate(bf)
    if est.need > free.bytes:
        biggest = ", ".join(f"{what} {size / KIB:.1f} KiB" for what, size in est.parts[:4])
        raise DoesNotFit(
            f"{bf.path}: does not fit the {bf.mcu}'s heap: its firmware needs about "
            f"{est.need / KIB:.0f} KiB, the {bf.mcu} has {free.bytes / KIB:.0f} KiB free after "
            f"MicroPython boots ({free.cite}); biggest: {biggest} (docs/hardware.md, "
            '"Memory")'
        )
    return est


def measure(node: str, micropython: Path) -> dict[str, Any]:
    """Measure the table again in the simulator (heapprobe.mjs): {"runtime", "bus",
    "modules" (by module), "instance" (by driver)}."""
    probe = Path(__file__).resolve().parent.parent / "virtual" / "world" / "heapprobe.mjs"
    spec = {"bus": PROBE_BUS, "entries": {d: {"driver": d, **e} for d, e in PROBE_ENTRIES.items()}}
    with tempfile.NamedTemporaryFile("w", suffix=".json") as f:
        json.dump(spec, f)
        f.flush()
        out = subprocess.run(
            [node, str(probe), f.name, str(micropython)],
            capture_output=True, text=True, timeout=300, check=True,
        ).stdout  # fmt: skip
    got: dict[str, Any] = json.loads(out.splitlines()[-1])
    modules: dict[str, int] = {}
    for driver, size in got["modules"].items():  # (the first driver of a module pays for it)
        module = DRIVERS[driver][0]
        modules[module] = max(modules.get(module, 0), size)
    got["modules"] = modules
    return got
