"""An AVR board file in simavr (``missing-link board --file F --runtime avr``): the firmware built
for its MCU and the rig (``firmware/avr/sim``) built for this machine, both kept in a cache by the
hash of what went into them, and the rig's parts at the board file's pins (rig_sim's ``--part``
specs: what each entry's part is, as virtual/world/parts.py makes them for MicroPython).

The parts: an encoder at its phases' pins, a Sharp (800 mm away) and a battery (7.4 V behind its
divider) on their ADC channels, an SRF02 and an MPU-6050 (at rest, level) at their TWI addresses,
a motor at its bridge's pins, a stepper driver, an HC-SR04, a GPS receiver on USART1 and its PPS;
the servo's and the trigger's pins are measured, not driven.  The k-th motor turns the k-th
encoder (a wheel: ``counts_per_rev`` edges a turn, the encoder entry's option, else
WHEEL_COUNTS; WHEEL_TOP turns/s at full drive).  An absent part (``--absent NAME``) is not made."""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Collection
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..errors import ConfigError
from .avr import AVR_DIR
from .avrpins import PINS
from .avrsize import check
from .avrstamp import check_id
from .boardfile import BoardFile
from .check import FlashError

#: the encoder's edges a wheel turn when its entry does not say (options.counts_per_rev)
WHEEL_COUNTS = 400
#: a wheel's turns a second at full drive
WHEEL_TOP = 2.0
#: the battery's pack voltage (virtual/world/pin_devices.py's BatteryPack)
PACK_VOLTS = 7.4
#: what a build needs, and where a Debian machine gets it
TOOLS = ("avr-gcc", "avr-objcopy", "make", "cc")
SIMAVR_HEADER = Path("/usr/include/simavr/sim_avr.h")
DEPS = "run scripts/system-deps.sh (avr-gcc, avr-libc, simavr, libsimavr-dev)"


@dataclass(frozen=True)
class SimBuild:
    """What runs a board file in simavr: the rig, the firmware, its MCU and the rig's parts."""

    rig: Path
    elf: Path
    mcu: str
    parts: tuple[str, ...]

    def command(self, eeprom: Path | None = None) -> list[str]:
        """rig_sim's command line (``eeprom``: where the EEPROM lives across power cycles)."""
        cmd = [str(self.rig), str(self.elf), "--mcu", self.mcu]
        for spec in self.parts:
            cmd += ["--part", spec]
        return cmd + (["--eeprom", str(eeprom)] if eeprom is not None else [])


def rig_parts(bf: BoardFile, absent: Collection[str] = ()) -> list[str]:
    """rig_sim's ``--part`` specs for the board file's parts, but the absent ones."""
    ports = PINS[bf.mcu].ports

    def pin(e: dict[str, Any], key: str) -> str:
        if e.get(key) is None:
            return "-"
        port, bit = ports[int(e[key])]
        return f"{port}{bit}"

    out: list[str] = []
    motors: list[int] = []
    encoders: list[tuple[int, float]] = []  # (index among the rig's encoders, counts a turn)
    for e in bf.transducers:
        drv = e["driver"]
        if e["name"] in absent:
            continue
        if drv == "quadrature":
            counts = (e.get("options") or {}).get("counts_per_rev", WHEEL_COUNTS)
            encoders.append((len(encoders), float(counts)))
            out.append(f"quadrature {pin(e, 'pin_a')} {pin(e, 'pin_b')}")
        elif drv in ("sharp_gp2y0a02",):
            out.append(f"sharp {int(e['pin'])}")
        elif drv == "battery":
            top, bottom = float(e.get("r_top", 10000.0)), float(e.get("r_bottom", 3300.0))
            out.append(f"ain {int(e['pin'])} {round(PACK_VOLTS * bottom / (top + bottom) * 1000)}")
        elif drv in ("srf02", "mpu6050"):
            out.append(f"{drv} 0x{int(e.get('address', 0x70 if drv == 'srf02' else 0x68)):02x}")
        elif drv == "hbridge":
            motors.append(len(motors))
            a, _b = PINS[bf.mcu].pwm or (None, None)
            if "in1" in e:
                out.append("motor 2 -")
            else:
                out.append(f"motor {0 if int(e['pwm_pin']) == a else 1} {pin(e, 'dir_pin')}")
        elif drv == "stepper":
            out.append(f"stepper {pin(e, 'step_pin')} {pin(e, 'dir_pin')} {pin(e, 'enable_pin')}")
        elif drv == "hcsr04":
            out.append(f"hcsr04 {pin(e, 'trig_pin')} {pin(e, 'echo_pin')}")
        elif drv == "gps_nmea":
            out.append(f"gps {pin(e, 'pps_pin')}")
    for k, (enc, counts) in zip(motors, encoders, strict=False):  # the k-th motor, k-th encoder
        out.append(f"wheel {k} {enc} {counts:g} {WHEEL_TOP:g}")
    return out


def _tools() -> None:
    missing = [t for t in TOOLS if shutil.which(t) is None]
    if not SIMAVR_HEADER.exists():
        missing.append("simavr (libsimavr-dev)")
    if missing:
        raise ConfigError(f"--runtime avr needs {', '.join(missing)}: {DEPS}")


def cache_dir() -> Path:
    """Where built firmware and rigs are kept ($XDG_CACHE_HOME/missing-link/avr)."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "missing-link" / "avr"


def _digest(*parts: bytes | Path) -> str:
    """The hash of bytes and of the files under paths (their names and contents)."""
    h = hashlib.sha256()
    for p in parts:
        if isinstance(p, bytes):
            h.update(p)
            continue
        for f in sorted(p.rglob("*") if p.is_dir() else [p]):
            if f.is_file() and "__pycache__" not in f.parts:
                h.update(str(f.relative_to(p.parent)).encode() + b"\0" + f.read_bytes())
    return h.hexdigest()[:20]


def _make(args: list[str], out: Path, what: str) -> None:
    """make in firmware/avr into a scratch directory, moved to ``out`` once built (two boards
    started at once build twice and keep one)."""
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix=".build-", dir=out.parent) as tmp:
        cmd = ["make", "-C", str(AVR_DIR), f"BUILD={tmp}", f"PYTHON={sys.executable}", *args]
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
        if r.returncode != 0:
            lines = [ln for ln in (r.stderr + r.stdout).splitlines() if ln.strip()]
            said = [ln for ln in lines if "error" in ln.lower()] or lines[-1:]
            raise FlashError(f"building {what} failed: {said[0] if said else r.returncode}")
        try:
            os.rename(tmp, out)
        except OSError:  # (built meanwhile by another: that one is as good)
            if not out.exists():
                raise


def build(bf: BoardFile, board_id: str, absent: Collection[str] = ()) -> SimBuild:
    """The firmware of ``bf`` (stamped with ``board_id``, taken by a board whose EEPROM has
    none) and the rig, from the cache or built into it; ConfigError naming what is missing to
    build them, DoesNotFit for a board file too big for its MCU."""
    if not bf.is_avr:
        raise ConfigError(f"{bf.path}: --runtime avr: mcu {bf.mcu!r} is not an AVR")
    _tools()
    cache = cache_dir()
    deploy = Path(__file__).resolve().parent
    rig_dir = cache / f"rig-{_digest(AVR_DIR / 'sim', AVR_DIR / 'Makefile')}"
    if not (rig_dir / "rig_sim").exists():
        _make(["sim"], rig_dir, "the simavr rig")
    generator = [deploy / f for f in sorted(os.listdir(deploy)) if f.endswith(".py")]
    key = _digest(bf.path.read_bytes(), check_id(board_id).encode(), AVR_DIR / "src",
                  AVR_DIR / "Makefile", *generator)  # fmt: skip
    fw = cache / f"fw-{key}"
    if not (fw / bf.name / "firmware.elf").exists():
        args = [f"BOARD={bf.path.resolve()}", f"ID={board_id}", "CHECK=0"]
        _make(args, fw, f"the firmware of {bf.path}")
    check(fw / bf.name / "firmware.elf", bf.mcu, str(bf.path))  # (DoesNotFit: one line)
    parts = tuple(rig_parts(bf, absent))
    return SimBuild(rig_dir / "rig_sim", fw / bf.name / "firmware.elf", bf.mcu, parts)
