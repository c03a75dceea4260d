"""The run-time configuration of an AVR board: the tables config.c serves (firmware/avr/src),
generated into ``board_gen.c`` from the same board file and the same driver CONFIG as a
MicroPython board's (``board/config.py``), so the key table's text, the defaults and the limits
are the same on both runtimes: the board file and the drivers stay their single source.

What the C runtime cannot change at run time is refused here, naming the entry."""

from __future__ import annotations

import inspect
import struct
from dataclasses import dataclass
from typing import Any

from ..board.config import DEFAULT_FAILSAFE_MS, Key, crc16
from ..board.runtime import Transducer
from ..errors import ConfigError
from .cgen import c_comment, c_text

#: per driver, the CONFIG keys the C drivers apply at run time, and the call that applies them
#: (``{name}``: the index of that key's value in v[]; ``{inst}``: which of the driver's
#: instances, for the drivers a board may have more than one of)
APPLY = {
    "quadrature": ("quadrature_set(&quad_{inst}, F(v[{rate_hz}]), (uint8_t)v[{reverse}]);", ()),
    "sharp_gp2y0a02": ("sharp_set(F(v[{rate_hz}]));", ()),
    "srf02": ("srf02_set(F(v[{rate_hz}]), (uint16_t)v[{min_range}]);", ("units",)),
    "servo": (
        "servo_set((uint16_t)v[{min_us}], (uint16_t)v[{max_us}], (uint16_t)v[{centre_us}], "
        "(uint16_t)v[{span_us}], (uint8_t)v[{safe}]);",
        (),
    ),
    "trigger": ("trigger_set((uint16_t)v[{pulse_us}]);", ()),
    "hbridge": ("hbridge_set({inst}, F(v[{ramp}]), (uint8_t)v[{stop}], v[{freq}]);", ()),
    "stepper": (
        "stepper_set(F(v[{max_speed}]), F(v[{accel}]), (uint8_t)v[{mode}]);",
        ("microsteps",),
    ),
    "hcsr04": (
        "hcsr04_set(F(v[{rate_hz}]), F(v[{temperature_c}]), (uint16_t)v[{max_range_cm}]);",
        (),
    ),
    "gps_nmea": ("", ()),
    "mpu6050": (
        "mpu6050_set(&mpu_{inst}, F(v[{rate_hz}]), (uint8_t)v[{accel_g}], (uint8_t)v[{gyro_dps}], "
        "(uint8_t)v[{dlpf}]);",
        (),
    ),
    "battery": (
        "battery_set(F(v[{rate_hz}]), F(v[{ratio}]), (uint8_t)v[{cells}], "
        "(uint8_t)v[{chemistry}]);",
        (),
    ),
}
#: sampling on the host-time grid (timing.c), for the drivers that align (``ALIGNABLE``)
ALIGN = {
    "quadrature": "quadrature_align(&quad_{inst}, (uint8_t)v[{aligned}], F(v[{phase}]));",
    "sharp_gp2y0a02": "sharp_align((uint8_t)v[{aligned}], F(v[{phase}]));",
    "srf02": "srf02_align((uint8_t)v[{aligned}], F(v[{phase}]));",
    "hcsr04": "hcsr04_align((uint8_t)v[{aligned}], F(v[{phase}]));",
    "battery": "battery_align((uint8_t)v[{aligned}], F(v[{phase}]));",
    "mpu6050": "mpu6050_align(&mpu_{inst}, (uint8_t)v[{aligned}], F(v[{phase}]));",
}
#: a combination a driver refuses (the Python driver's check_config, in C)
CHECK = {
    "servo": (
        "(int32_t)v[{min_us}] < (int32_t)v[{centre_us}] && "
        "(int32_t)v[{centre_us}] < (int32_t)v[{max_us}]",
        "need min_us < centre_us < max_us",
    ),
}
#: config.c's CONFIG_MAX: the run-time keys an MCU's RAM holds (three copies on the stack)
MAX_KEYS = {"atmega328p": 32, "atmega2560": 64, "atmega32u4": 32}
EEPROM = {"atmega328p": 1024, "atmega2560": 4096, "atmega32u4": 1024}
_KIND = {"bool": "KIND_BOOL", "int": "KIND_INT", "float": "KIND_FLOAT", "enum": "KIND_ENUM"}


@dataclass
class AvrKey:
    key: Key
    k: int  #: the transducer's index in board_transducers[]
    driver: str
    inst: int = 0  #: which of its driver's instances (hbridge: 0 or 1)


def default_of(cls: type, entry: dict[str, Any], key: str, limits: Any) -> Any:
    """A key's value at boot, as the Python driver computes it from the board file entry."""
    params = inspect.signature(cls.__init__).parameters  # type: ignore[misc]
    value = entry.get(key, params[key].default if key in params else None)
    if key == "ratio" and key not in params:  # the battery's divider, as its __init__ has it
        top = float(entry.get("r_top", params["r_top"].default))
        bottom = float(entry.get("r_bottom", params["r_bottom"].default))
        return (top + bottom) / bottom
    if key == "rate_hz":  # Periodic: capped to the limit, the period in whole µs
        rate = min(float(value or 0), float(limits[1]))
        return round(1e6 / int(1e6 / rate), 3)
    return value


def keys_of(
    transducers: list[tuple[int, dict[str, Any], Transducer, type]],
    where: str,
    aligned: bool = True,
    mcu: str = "atmega328p",
) -> list[AvrKey]:
    """The run-time keys, as board/config.py makes them; without ``aligned`` (an image without
    the timing feature) no aligned/phase keys; at most as many as ``mcu``'s firmware holds."""
    out: list[AvrKey] = []
    count: dict[str, int] = {}
    for k, entry, t, cls in transducers:
        drv = entry["driver"]
        inst = count.get(drv, 0)
        count[drv] = inst + 1

        def add(key: Key, k: int = k, drv: str = drv, inst: int = inst) -> None:
            out.append(AvrKey(key, k, drv, inst))

        add(Key(t, "enabled", "bool", None, False, lambda: True, None))
        if aligned and getattr(cls, "ALIGNABLE", False):  # (as board/config.py adds them)
            if drv not in ALIGN:
                raise ConfigError(f"{where}: {t.name}: {drv} cannot align on AVR")
            add(Key(t, "aligned", "bool", None, False, lambda: False, None))
            add(Key(t, "phase", "float", (0.0, 0.999), False, lambda: 0.0, None))
        if hasattr(cls, "make_safe"):  # the failsafe's (failsafe.c), as board/config.py adds it
            ms = int(entry.get("failsafe_ms", DEFAULT_FAILSAFE_MS))
            add(Key(t, "failsafe_ms", "int", (0, 60000), False, lambda v=ms: v, None))
        apply, read_only = APPLY[entry["driver"]]
        for key, kind, limits, ro in cls.CONFIG:  # type: ignore[attr-defined]
            if f"{{{key}}}" not in apply and key not in read_only:
                raise ConfigError(f"{where}: {t.name}: key {key} cannot change at run time on AVR")
            value = default_of(cls, entry, key, limits)
            if key == "units" and value != "cm":
                raise ConfigError(f"{where}: {t.name}: the AVR SRF02 measures in cm only")
            add(Key(t, key, kind, limits, ro, lambda v=value: v, None))
    most = MAX_KEYS.get(mcu, 32)
    if len(out) > most:
        raise ConfigError(
            f"{where}: {len(out)} run-time keys, the AVR runtime has room for {most} on the {mcu}"
        )
    return out


def _raw(kind: str, value: Any, limits: Any) -> int:
    if kind == "float":
        return int(struct.unpack("<I", struct.pack("<f", float(value)))[0])
    if kind == "enum":
        return int(limits.index(value))
    return int(value) & 0xFFFFFFFF


def keys_blob(keys: list[AvrKey]) -> bytes:
    return ("config/1\n" + "".join(a.key.line() + "\n" for a in keys)).encode()


def generate_config(
    keys: list[AvrKey],
    mcu: str,
    where: str,
    wiring: dict[int, list[tuple[str, str]]] | None = None,
) -> tuple[list[str], bytes]:
    """(C lines of the tables and the two generated functions, the key table's text).
    ``wiring``: per transducer index, conditions a set must keep that depend on how the entry
    is wired (avrdrivers.py: a PWM/DIR bridge cannot brake)."""
    slot = 1 + 9 + 4 * len(keys)
    if 16 + 2 * slot > EEPROM[mcu] - 32:  # (the last 32 bytes: board.id, identity.c)
        raise ConfigError(f"{where}: the configuration record does not fit the {mcu}'s EEPROM")
    blob = keys_blob(keys)
    limits: list[tuple[int, int]] = []  # (keys share their limits: a pair each, once)
    rows = [_key_row(a.key, limits) for a in keys]
    cases, checks = _apply_cases(keys, wiring or {})
    n = len(keys)
    return [
        "/* run-time configuration (config.c): keys, limits and defaults from the board file */",
        f"const config_row_t board_config_keys[{max(n, 1)}] PROGMEM = {{",
        *rows,
        "};",
        "const uint32_t board_config_limits[] PROGMEM = {",
        *(f"    0x{lo:08x}UL, 0x{hi:08x}UL," for lo, hi in limits or [(0, 0)]),
        "};",
        f"const uint8_t board_config_count = {n};",
        f"uint32_t board_config_values[{max(n, 1)}];",
        f"const uint16_t board_config_schema_crc = 0x{crc16(blob):04x};",
        f"static const char config_keys[] PROGMEM = {{{', '.join(str(b) for b in blob)}, 0}};",
        f"static uint16_t config_keys_len(void) {{ return {len(blob)}; }}",
        "static uint8_t config_keys_at(uint16_t i) { return pgm_read_byte(config_keys + i); }",
        "extern uint16_t board_failsafe_ms[];",
        "const blob_t board_config_keys_blob = {config_keys_len, config_keys_at};",
        "static float F(uint32_t raw) { float f; memcpy(&f, &raw, 4); return f; }",
        "void board_config_apply(const uint32_t *v, uint8_t i) {",
        "    (void)F;",
        "    switch (i) {",
        *cases,
        "    default: break;",
        "    }",
        "}",
        "const char *board_config_check(const uint32_t *v) {",
        "    (void)v;",
        *checks,
        "    return 0;",
        "}",
    ], blob


def _key_row(key: Key, limits: list[tuple[int, int]]) -> str:
    """A key's row in the table: its kind and read-only flag, its limits' pair (added to
    ``limits`` if new), its default, raw."""
    if key.kind == "enum":
        lo, hi = 0, len(key.limits) - 1
    elif key.limits is None:
        lo, hi = 0, 1
    else:
        lo, hi = (_raw(key.kind, x, None) for x in key.limits)
    if (lo, hi) not in limits:
        limits.append((lo, hi))
    return (
        f"    {{{_KIND[key.kind]}{' | CONFIG_RO' if key.read_only else ''}, "
        f"{limits.index((lo, hi))}, 0x{_raw(key.kind, key.default, key.limits):08x}UL}}, "
        f"/* {c_comment(key.name)} */"
    )


def _apply_cases(
    keys: list[AvrKey], wiring: dict[int, list[tuple[str, str]]]
) -> tuple[list[str], list[str]]:
    """(the switch's case per key: what a set of it does, the checks a set must pass)."""
    index: dict[tuple[int, str], int] = {(a.k, a.key.key): i for i, a in enumerate(keys)}
    cases, checks, drivers_done = [], [], set()
    safe_slots: dict[int, int] = {}  # transducer -> its place in the failsafe's table
    for i, a in enumerate(keys):
        key = a.key
        sibling = {name: j for (k, name), j in index.items() if k == a.k}
        if key.key == "enabled":
            cases.append(
                f"    case {i}: board_transducers[{a.k}].enabled = (uint8_t)v[{i}]; "
                f"if (!v[{i}]) board_transducers[{a.k}].pending = 0; break;"
            )
        elif key.key in ("aligned", "phase"):
            cases.append(f"    case {i}: {ALIGN[a.driver].format(inst=a.inst, **sibling)} break;")
        elif key.key == "failsafe_ms":
            slot = safe_slots.setdefault(a.k, len(safe_slots))
            cases.append(f"    case {i}: board_failsafe_ms[{slot}] = (uint16_t)v[{i}]; break;")
        elif not key.read_only:
            drv = a.driver
            apply = APPLY[drv][0].format(inst=a.inst, **sibling)
            cases.append(f"    case {i}: {apply} break;")
            if a.k not in drivers_done:
                drivers_done.add(a.k)
                conds = ([CHECK[drv]] if drv in CHECK else []) + wiring.get(a.k, [])
                for cond, why in conds:
                    text = c_text(f"{key.t.name}: {why}")
                    checks.append(f"    if (!({cond.format(**sibling)})) return PSTR({text});")
    return cases, checks
