"""``missing-link gen-firmware BOARDFILE --target avr``: the C tables of an AVR board
(``board_gen.c``) from the same board file a MicroPython board uses.

The transducer descriptors are made by the same code as on MicroPython
(``board.firmware.describe``), so both firmwares describe a board file byte for byte alike.  The
C runtime (firmware/avr/src) owns the hardware, so each driver exists once and on fixed pins;
what the board file asks that the hardware cannot do is refused here, naming the entry."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..board.drivers import driver_class
from ..board.dtypes import DTYPES
from ..board.firmware import describe
from ..board.runtime import Transducer
from ..errors import ConfigError
from .avrconfig import generate_config, keys_of
from .avrdrivers import AVR_DRIVERS, Part, part_of
from .avrpins import PINS
from .boardfile import BoardFile

DT = {"int8_t": "DT_INT8", "uint8_t": "DT_UINT8", "int16_t": "DT_INT16", "uint16_t": "DT_UINT16",
      "int32_t": "DT_INT32", "uint32_t": "DT_UINT32", "float": "DT_FLOAT"}  # fmt: skip
MAX_SIF_PAYLOAD = 120  # the TX ring (256) must hold a SIF's worst-case escaping


def _c_string(data: bytes) -> str:
    """A C string literal for arbitrary bytes (NULs included), split into lines."""
    parts, line = [], ""
    for b in data:
        ch = chr(b)
        if ch == "\\" or ch == '"':
            line += "\\" + ch
        elif 32 <= b < 127:
            line += ch
        else:
            line += f"\\{b:03o}"  # always 3 octal digits: a digit after it stays a digit
        if b in (0, 10) and len(line) > 60:
            parts.append(f'"{line}"')
            line = ""
    parts.append(f'"{line}"')
    return "\n    ".join(parts)


def _props(pairs: list[tuple[str, str]]) -> bytes:
    return b"".join(k.encode() + b"\0" + v.encode() + b"\0" for k, v in pairs)


def _na_raw(dtype: str, na: float) -> str:
    import struct

    code, size = DTYPES[dtype][0], DTYPES[dtype][1]
    raw = struct.pack("<" + code, na) + bytes(4 - size)
    return f"0x{struct.unpack('<I', raw)[0]:08x}UL"


def generate_avr(bf: BoardFile) -> str:
    """The C source of board_gen.c for ``bf``; ConfigError for what an AVR cannot do."""
    where = str(bf.path)
    if not bf.is_avr:
        raise ConfigError(f"{where}: mcu {bf.mcu!r} is not an AVR (atmega328p/2560/32u4)")
    pins = PINS[bf.mcu]
    board = bf.board
    count: dict[str, int] = {}
    decls, setup, polls, funcs, lines = [], [], [], [], ["transds/1"]
    hardware: list[tuple[str, str, str]] = []  # timed calls the hardware makes (the trigger's)
    safe: list[tuple[int, str]] = []  # (transducer index, make_safe): the failsafe's actuators
    isrs: list[str] = []
    checks: dict[int, list[tuple[str, str]]] = {}
    described: list[tuple[int, dict[str, Any], Transducer, type]] = []
    for k, e in enumerate(bf.transducers):
        drv, name = e["driver"], e["name"]
        at = f"{where}: {name}"
        if drv not in AVR_DRIVERS:
            known = ", ".join(AVR_DRIVERS)
            raise ConfigError(f"{at}: driver {drv} is not in the AVR runtime ({known})")
        inst = count.get(drv, 0)
        if inst >= AVR_DRIVERS[drv]:
            most = AVR_DRIVERS[drv]
            raise ConfigError(
                f"{at}: {'a second' if most == 1 else f'more than {most}'} {drv}: the AVR "
                f"runtime has {most} (fixed hardware)"
            )
        count[drv] = inst + 1
        cls = driver_class(drv)
        t = describe(e, cls)
        described.append((k, e, t, cls))
        if t.dtype not in DT:
            raise ConfigError(f"{at}: type {t.dtype} is not supported on AVR")
        if t.chan_count * (8 + DTYPES[t.dtype][1]) > MAX_SIF_PAYLOAD:
            raise ConfigError(f"{at}: its SIF would exceed {MAX_SIF_PAYLOAD} bytes on AVR")
        lines.append(t.descriptor_line())
        size = DTYPES[t.dtype][1]
        decls.append(f"static uint64_t stamps_{k}[{t.chan_count}];")
        decls.append(f"static uint32_t values_{k}[{t.chan_count}];")
        part: Part = part_of(k, e, t, pins, bf.mcu, inst, at)
        setup += part.setup
        polls += part.polls
        decls += part.decls
        funcs += part.funcs
        hardware += part.hardware
        isrs += part.isrs
        if part.make_safe:
            safe.append((k, part.make_safe))
        if part.checks:
            checks[k] = part.checks
        na = _na_raw(t.dtype, t.na)
        decls.append(f"/* transducer {k}: {name} */")
        decls.append(
            f"#define T_{k} {{{t.tid}, {DT[t.dtype]}, {t.chan_count}, {size}, {na}, 0, "
            f"stamps_{k}, values_{k}, 0, 1}}"
        )
    transds = ("\n".join(lines) + "\n").encode()
    head = (
        _props(
            [
                ("j2a.version", "2"),
                ("board.name", bf.name),
                ("board.model", str(board.get("model", f"missing-link {bf.mcu} board"))),
                ("board.serial", str(board.get("serial", f"avr-{bf.name}"))),
            ]
        )
        + b"clock.epoch\0"
    )
    fw = str(board.get("fw_version", "0.2.0"))
    tail = b"\0" + _props([("clock.res_us", "1"), ("fw.version", fw)])
    n = len(bf.transducers)
    out = [
        "/* Generated by `missing-link gen-firmware` from " + bf.path.name + ": do not edit. */",
        "#include <avr/interrupt.h>",
        "#include <avr/pgmspace.h>",
        "#include <string.h>",
        '#include "builtins.h"',
        '#include "config.h"',
        '#include "drivers.h"',
        '#include "failsafe.h"',
        '#include "gps_nmea.h"',
        '#include "hbridge.h"',
        '#include "hcsr04.h"',
        '#include "runtime.h"',
        '#include "stepper.h"',
        '#include "timing.h"',
        "",
        *decls,
        *isrs,
        f"transducer_t board_transducers[{n}] = {{{', '.join(f'T_{k}' for k in range(n))}}};",
        f"const uint8_t board_transducer_count = {n};",
        "",
        f"static const char transds[] PROGMEM = {_c_string(transds)};",
        f"static uint16_t transds_len(void) {{ return {len(transds)}; }}",
        "static uint8_t transds_at(uint16_t i) { return pgm_read_byte(transds + i); }",
        "const blob_t board_transds_blob = {transds_len, transds_at};",
        "",
        "/* properties: the fixed head and tail in flash, clock.epoch (per boot) in RAM between */",
        f"static const char props_head[] PROGMEM = {_c_string(head)};",
        f"static const char props_tail[] PROGMEM = {_c_string(tail)};",
        f"#define HEAD {len(head)}",
        f"#define TAIL {len(tail)}",
        "static uint16_t props_len(void) { return HEAD + strlen(clock_epoch) + TAIL; }",
        "static uint8_t props_at(uint16_t i) {",
        "    if (i < HEAD) return pgm_read_byte(props_head + i);",
        "    i -= HEAD;",
        "    uint16_t e = strlen(clock_epoch);",
        "    if (i < e) return (uint8_t)clock_epoch[i];",
        "    return pgm_read_byte(props_tail + (i - e));",
        "}",
        "const blob_t board_properties_blob = {props_len, props_at};",
        "",
    ]
    config_c, _blob = generate_config(keys_of(described, where), bf.mcu, where, checks)
    out += [*config_c, ""]
    # the failsafe's actuators (failsafe.c): their names for its debug text, their make_safe
    for k, _fn in safe:
        out.append(f'static const char safe_name_{k}[] PROGMEM = "{bf.transducers[k]["name"]}";')
    rows = ", ".join(f"{{{k}, safe_name_{k}, {fn}}}" for k, fn in safe)
    out += [
        f"static const failsafe_entry_t failsafe_table[{max(len(safe), 1)}] PROGMEM = {{{rows}}};",
        f"uint16_t board_failsafe_ms[{max(len(safe), 1)}] = "
        f"{{{', '.join(str(int(bf.transducers[k].get('failsafe_ms', 500))) for k, _f in safe)}}};"
        " /* the board file's; config.c sets them at run time */",
        "",
    ]
    if hardware:  # (the trigger's function index: builtins, then the board's own functions)
        index = {name: 11 + j for j, (name, _fn) in enumerate(funcs)}
        out += [
            "static uint8_t hardware(uint8_t fn, uint64_t tick, const uint8_t *payload, "
            "uint8_t n) {",
            *(
                f"    if (fn == {index[call]} && {enabled}) return {fn}(payload, n, tick);"
                for call, enabled, fn in hardware
            ),
            "    return 0;",
            "}",
            "",
        ]
    for j, (fname, _fn) in enumerate(funcs):
        out.append(f'static const char fname_{j}[] PROGMEM = "{fname}";')
    own = "".join(f", {{fname_{j}, KIND_PLAIN, {fn}, 0}}" for j, (_f, fn) in enumerate(funcs))
    own += ", {n_at, KIND_PLAIN, timing_at, 0}, {n_align_info, KIND_PLAIN, timing_info, 0}"
    own += ", {n_goodbye, KIND_PLAIN, failsafe_goodbye, 0}"
    own += ", {n_failsafe, KIND_PLAIN, failsafe_info, 0}"
    own += ", {n_config_keys, KIND_BLOB, 0, &board_config_keys_blob}"
    own += ", {n_config_get, KIND_PLAIN, config_get, 0}, {n_config_set, KIND_PLAIN, config_set, 0}"
    own += ", {n_config_reset, KIND_PLAIN, config_reset, 0}"
    out += [
        'static const char n_at[] PROGMEM = "a2jAt";',
        'static const char n_align_info[] PROGMEM = "a2jAlignInfo";',
        'static const char n_goodbye[] PROGMEM = "a2jGoodbye";',
        'static const char n_failsafe[] PROGMEM = "a2jFailsafe";',
        'static const char n_config_keys[] PROGMEM = "a2jConfigKeys";',
        'static const char n_config_get[] PROGMEM = "a2jConfigGet";',
        'static const char n_config_set[] PROGMEM = "a2jConfigSet";',
        'static const char n_config_reset[] PROGMEM = "a2jConfigReset";',
        f"const function_t board_functions[] PROGMEM = {{BUILTIN_FUNCTIONS{own}}};",
        f"const uint8_t board_function_count = BUILTIN_COUNT + {len(funcs) + 8};",
        "",
        "void board_setup(void) {",
    ]
    out += [f"    {line}" for line in setup]
    out += [f"    failsafe_init(failsafe_table, board_failsafe_ms, {len(safe)});"]
    out += ["    config_boot(); /* the saved configuration, if any (config.c) */"]
    out += ["}", "", "void board_poll(uint64_t now) {"]
    out += [f"    {line}" for line in polls] or ["    (void)now;"]
    out += ["}", ""]
    return "\n".join(out)


def write_avr(bf: BoardFile, out_dir: Path) -> list[Path]:
    """Write board_gen.c and board.mk (MCU, baud) into out_dir; returns the files."""
    src = generate_avr(bf)
    out_dir.mkdir(parents=True, exist_ok=True)
    c = out_dir / "board_gen.c"
    c.write_text(src)
    link = bf.board.get("link", {})
    baud = int(link.get("baudrate", 115200))
    mk = out_dir / "board.mk"
    mk.write_text(f"MCU = {bf.mcu}\nBAUD = {baud}\nNAME = {bf.name}\n")
    return [c, mk]
