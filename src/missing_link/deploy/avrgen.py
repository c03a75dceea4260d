"""``missing-link gen-firmware BOARDFILE --target avr``: the C tables of an AVR board
(``board_gen.c``) from the same board file a MicroPython board uses.

The transducer descriptors are made by the same code as on MicroPython
(``board.firmware.describe``), so both firmwares describe a board file byte for byte alike.  The
C runtime (firmware/avr/src) owns the hardware, so each driver exists once and on fixed pins;
what the board file asks that the hardware cannot do is refused here, naming the entry."""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..board.drivers import driver_class
from ..board.dtypes import DTYPES
from ..board.firmware import describe
from ..board.runtime import Transducer
from ..errors import ConfigError
from .avrconfig import generate_config, keys_of
from .avrdrivers import AVR_DRIVERS, DRIVER_SOURCES, Part, link_claims, part_of
from .avrpins import PINS
from .boardfile import FEATURES, BoardFile
from .cgen import c_comment, c_ident, c_string

DT = {"int8_t": "DT_INT8", "uint8_t": "DT_UINT8", "int16_t": "DT_INT16", "uint16_t": "DT_UINT16",
      "int32_t": "DT_INT32", "uint32_t": "DT_UINT32", "float": "DT_FLOAT"}  # fmt: skip
MAX_SIF_PAYLOAD = 120  # the TX ring (256) must hold a SIF's worst-case escaping


def _props(pairs: list[tuple[str, str]]) -> bytes:
    return b"".join(k.encode() + b"\0" + v.encode() + b"\0" for k, v in pairs)


def _na_raw(dtype: str, na: float) -> str:
    code, size = DTYPES[dtype][0], DTYPES[dtype][1]
    raw = struct.pack("<" + code, na) + bytes(4 - size)
    return f"0x{struct.unpack('<I', raw)[0]:08x}UL"


@dataclass
class Parts:
    """Every entry's part (avrdrivers.py), gathered in board file order: their code as one
    (``code.decls``: ``board_gen.c``'s declarations), the actuators' make_safe by entry index."""

    code: Part = field(default_factory=Part)
    safe: list[tuple[int, str]] = field(default_factory=list)  #: (index, make_safe)
    claims: dict[int, str] = field(default_factory=link_claims)  #: pin -> who has it
    checks: dict[int, list[tuple[str, str]]] = field(default_factory=dict)
    lines: list[str] = field(default_factory=lambda: ["transds/1"])  #: the descriptor
    described: list[tuple[int, dict[str, Any], Transducer, type]] = field(default_factory=list)


def generate_avr(bf: BoardFile) -> str:
    """The C source of board_gen.c for ``bf``; ConfigError for what an AVR cannot do."""
    where = str(bf.path)
    if not bf.is_avr:
        raise ConfigError(f"{where}: mcu {bf.mcu!r} is not an AVR (atmega328p/2560/32u4)")
    c_ident(bf.name, f"{where}: name")
    parts = collect_parts(bf, where)
    n = len(bf.transducers)
    out = [*_head(bf), *parts.code.decls, *_isrs(parts.code.isrs)]
    out += [
        f"transducer_t board_transducers[{n}] = {{{', '.join(f'T_{k}' for k in range(n))}}};",
        f"const uint8_t board_transducer_count = {n};",
        "",
    ]
    out += _blobs(bf, parts.lines)
    features = bf.features
    if "config" in features:
        keys = keys_of(parts.described, where, aligned="timing" in features, mcu=bf.mcu)
        config_c, _blob = generate_config(keys, bf.mcu, where, parts.checks)
        out += [*config_c, ""]
    out += _failsafe_table(bf, parts.safe)
    if "timing" in features:
        out += _hardware_dispatch(parts)
    else:  # (no timed calls for the hardware to take)
        parts.code.setup = [ln for ln in parts.code.setup if not ln.startswith("timing_hardware =")]
    out += _function_table(parts.code.funcs, features)
    out += _setup_and_poll(parts, features)
    return "\n".join(out)


def collect_parts(bf: BoardFile, where: str) -> Parts:
    """Each entry checked against the AVR runtime and turned into its part of the C."""
    pins = PINS[bf.mcu]
    count: dict[str, int] = {}
    parts = Parts()
    for k, e in enumerate(bf.transducers):
        drv = e["driver"]
        at = f"{where}: {c_ident(e['name'], f'{where}: transducers[{k}] name')}"
        if drv not in AVR_DRIVERS:
            known = ", ".join(AVR_DRIVERS)
            raise ConfigError(f"{at}: driver {drv} is not in the AVR runtime ({known})")
        inst = count.get(drv, 0)
        most = AVR_DRIVERS[drv]
        if inst >= most:
            raise ConfigError(
                f"{at}: {'a second' if most == 1 else f'more than {most}'} {drv}: the AVR "
                f"runtime has {most} (fixed hardware)"
            )
        count[drv] = inst + 1
        try:
            _add_entry(parts, k, e, inst, pins, bf.mcu, at)
        except ConfigError:  # (a ValueError too, already naming the file and the entry: once)
            raise
        except (ValueError, TypeError, KeyError, struct.error) as err:  # a dict no loader checked
            raise ConfigError(f"{at}: {err}") from None
    return parts


def _add_entry(
    parts: Parts, k: int, e: dict[str, Any], inst: int, pins: Any, mcu: str, at: str
) -> None:
    cls = driver_class(e["driver"])
    t = describe(e, cls)
    parts.described.append((k, e, t, cls))
    if t.dtype not in DT:
        raise ConfigError(f"{at}: type {t.dtype} is not supported on AVR")
    if t.chan_count * (8 + DTYPES[t.dtype][1]) > MAX_SIF_PAYLOAD:
        raise ConfigError(f"{at}: its SIF would exceed {MAX_SIF_PAYLOAD} bytes on AVR")
    if t.chan_count > 16:  # (runtime.h: a bit per channel in a uint16_t)
        raise ConfigError(f"{at}: {t.chan_count} channels; the AVR runtime keeps 16 at most")
    parts.lines.append(t.descriptor_line())
    parts.code.decls.append(f"static uint32_t stamps_{k}[{t.chan_count}];")
    parts.code.decls.append(f"static uint32_t values_{k}[{t.chan_count}];")
    part: Part = part_of(k, e, t, pins, mcu, inst, at, parts.claims)
    for call, _fn in part.funcs:
        c_ident(call, f"{at}: call")
    parts.code.gather(part)
    if part.make_safe:
        parts.safe.append((k, part.make_safe))
    if part.checks:
        parts.checks[k] = part.checks
    size = DTYPES[t.dtype][1]
    parts.code.decls.append(f"/* transducer {k}: {t.name} */")
    parts.code.decls.append(
        f"#define T_{k} {{{t.tid}, {DT[t.dtype]}, {t.chan_count}, {size}, "
        f"{_na_raw(t.dtype, t.na)}, 0, stamps_{k}, values_{k}, 0, 1}}"
    )


def _isrs(isrs: list[tuple[str, str]]) -> list[str]:
    """An interrupt routine per vector, with every statement the parts put in it (a port's
    pin-change interrupt serves all its pins: two encoders, an echo); a routine the same as one
    before it is an alias of that one (no second copy in flash)."""
    bodies: dict[str, list[str]] = {}
    for vector, statement in isrs:
        got = bodies.setdefault(vector, [])
        if statement not in got:  # (an encoder with both phases on one port: once)
            got.append(statement)
    out: list[str] = []
    seen: dict[str, str] = {}  # routine -> the vector that has it
    for vector, statements in bodies.items():
        body = " ".join(statements)
        if body in seen:
            out.append(f"ISR({vector}, ISR_ALIASOF({seen[body]}));")
        else:
            seen[body] = vector
            out.append(f"ISR({vector}) {{ {body} }}")
    return out


#: the C runtime's headers (firmware/avr/src)
HEADERS = ("<avr/interrupt.h>", "<avr/pgmspace.h>", "<string.h>", '"battery.h"', '"builtins.h"',
           '"config.h"', '"drivers.h"', '"failsafe.h"', '"gps_nmea.h"', '"hbridge.h"',
           '"hcsr04.h"', '"identity.h"', '"log.h"', '"memory.h"', '"mpu6050.h"',
           '"quadrature.h"', '"runtime.h"', '"stepper.h"', '"timing.h"')  # fmt: skip


def _head(bf: BoardFile) -> list[str]:
    name = c_comment(bf.path.name)
    return [
        f"/* Generated by `missing-link gen-firmware` from {name}: do not edit. */",
        *(f"#include {h}" for h in HEADERS),
        "",
    ]


#: where fw.hash goes in the image: deploy/avrstamp.py stamps the hash of the image over it
FW_HASH_PLACEHOLDER = "@@fwhash-stamp@@"
#: a part of the properties blob: text in flash, or what the board knows only at run time
Segment = bytes | str
_RUNTIME = {"id": ("identity_len()", "identity_at"), "epoch": ("strlen(clock_epoch)", "EPOCH_AT")}


def property_segments(bf: BoardFile) -> list[Segment]:
    """The properties blob as parts: text (flash) and "id" (board.id, in the EEPROM:
    identity.c) or "epoch" (clock.epoch, per boot, in RAM).  board.serial is board.id unless
    the board file names a serial."""
    board = bf.board
    serial = board.get("serial")
    fw = str(board.get("fw_version", "0.2.0"))
    model = str(board.get("model", f"missing-link {bf.mcu} board"))
    head = _props([("j2a.version", "2"), ("board.name", bf.name), ("board.model", model)])
    tail = _props([("clock.res_us", "1"), ("fw.version", fw), ("fw.hash", FW_HASH_PLACEHOLDER)])
    if serial is not None:
        head += _props([("board.serial", str(serial))])
        return [head + b"board.id\0", "id", b"\0clock.epoch\0", "epoch", b"\0" + tail]
    return [head + b"board.serial\0", "id", b"\0board.id\0", "id", b"\0clock.epoch\0", "epoch",
            b"\0" + tail]  # fmt: skip


def _properties_c(segments: list[Segment]) -> list[str]:
    """props_len and props_at over the segments, in order."""
    out = []
    lens = []
    at = ["static uint8_t props_at(uint16_t i) {", "    uint16_t n;"]
    for k, seg in enumerate(segments):
        if isinstance(seg, bytes):
            out.append(f"static const char props_{k}[] PROGMEM = {c_string(seg)};")
            size, read = str(len(seg)), f"pgm_read_byte(props_{k} + i)"
        else:
            size, fn = _RUNTIME[seg]
            read = f"(uint8_t){fn}(i)"
        lens.append(size)
        at += [f"    n = {size};", f"    if (i < n) return {read};", "    i -= n;"]
    return [
        *out,
        "#define EPOCH_AT(i) (clock_epoch[i])",
        f"static uint16_t props_len(void) {{ return {' + '.join(lens)}; }}",
        *at,
        "    return 0;",
        "}",
        "const blob_t board_properties_blob = {props_len, props_at};",
        "",
    ]


def _blobs(bf: BoardFile, lines: list[str]) -> list[str]:
    """The descriptor and the properties (board.id from the EEPROM, clock.epoch set per boot
    in RAM, the rest in flash)."""
    transds = ("\n".join(lines) + "\n").encode()
    return [
        f"static const char transds[] PROGMEM = {c_string(transds)};",
        f"static uint16_t transds_len(void) {{ return {len(transds)}; }}",
        "static uint8_t transds_at(uint16_t i) { return pgm_read_byte(transds + i); }",
        "const blob_t board_transds_blob = {transds_len, transds_at};",
        "",
        "/* properties: text in flash, board.id in the EEPROM (identity.c), clock.epoch in RAM */",
        *_properties_c(property_segments(bf)),
    ]


def _failsafe_table(bf: BoardFile, safe: list[tuple[int, str]]) -> list[str]:
    """The failsafe's actuators (failsafe.c): their names for its debug text, their make_safe."""
    out = [
        f"static const char safe_name_{k}[] PROGMEM = "
        f"{c_string(str(bf.transducers[k]['name']).encode())};"
        for k, _fn in safe
    ]
    rows = ", ".join(f"{{{k}, safe_name_{k}, {fn}}}" for k, fn in safe)
    ms = ", ".join(str(int(bf.transducers[k].get("failsafe_ms", 500))) for k, _f in safe)
    return [
        *out,
        f"static const failsafe_entry_t failsafe_table[{max(len(safe), 1)}] PROGMEM = {{{rows}}};",
        f"uint16_t board_failsafe_ms[{max(len(safe), 1)}] = {{{ms}}};"
        " /* the board file's; config.c sets them at run time */",
        "",
    ]


def _hardware_dispatch(parts: Parts) -> list[str]:
    """The timed calls the hardware makes (the trigger's), by function index: the builtins,
    then the board's own functions."""
    if not parts.code.hardware:
        return []
    index = {name: 11 + j for j, (name, _fn) in enumerate(parts.code.funcs)}  # (builtins.h, timing)
    return [
        "static uint8_t hardware(uint8_t fn, uint32_t tick, const uint8_t *payload, uint8_t n) {",
        *(
            f"    if (fn == {index[call]} && {enabled}) return {fn}(payload, n, tick);"
            for call, enabled, fn in parts.code.hardware
        ),
        "    return 0;",
        "}",
        "",
    ]


#: the functions a board has after its own (J2A name, kind, C function, blob, the feature they
#: come with: "" for every board)
FIXED_FUNCTIONS = (
    ("a2jAt", "KIND_PLAIN", "timing_at", "0", "timing"),
    ("a2jAlignInfo", "KIND_PLAIN", "timing_info", "0", "timing"),
    ("a2jGoodbye", "KIND_PLAIN", "failsafe_goodbye", "0", ""),
    ("a2jFailsafe", "KIND_PLAIN", "failsafe_info", "0", ""),
    ("a2jConfigKeys", "KIND_BLOB", "0", "&board_config_keys_blob", "config"),
    ("a2jConfigGet", "KIND_PLAIN", "config_get", "0", "config"),
    ("a2jConfigSet", "KIND_PLAIN", "config_set", "0", "config"),
    ("a2jConfigReset", "KIND_PLAIN", "config_reset", "0", "config"),
    ("a2jLogInfo", "KIND_PLAIN", "log_info", "0", "log"),
    ("a2jMemory", "KIND_PLAIN", "memory_info", "0", ""),
)


def _function_table(funcs: list[tuple[str, str]], features: tuple[str, ...]) -> list[str]:
    """The J2A function table: the builtins, the board's own (their names escaped as C strings
    besides being identifiers), then the fixed ones of the features it has."""
    out = [
        f"static const char fname_{j}[] PROGMEM = {c_string(fname.encode())};"
        for j, (fname, _fn) in enumerate(funcs)
    ]
    rows = [f"{{fname_{j}, KIND_PLAIN, {fn}, 0}}" for j, (_f, fn) in enumerate(funcs)]
    fixed = [f[:4] for f in FIXED_FUNCTIONS if not f[4] or f[4] in features]
    for j, (name, kind, fn, blob) in enumerate(fixed):
        out.append(f"static const char n_fixed_{j}[] PROGMEM = {c_string(name.encode())};")
        rows.append(f"{{n_fixed_{j}, {kind}, {fn}, {blob}}}")
    return [
        *out,
        f"const function_t board_functions[] PROGMEM = {{BUILTIN_FUNCTIONS, {', '.join(rows)}}};",
        f"const uint8_t board_function_count = BUILTIN_COUNT + {len(rows)};",
        "",
    ]


def _setup_and_poll(parts: Parts, features: tuple[str, ...]) -> list[str]:
    boot = ["    config_boot(); /* the saved configuration, if any (config.c) */"]
    return [
        "void board_setup(void) {",
        *(f"    {line}" for line in parts.code.setup),
        f"    failsafe_init(failsafe_table, board_failsafe_ms, {len(parts.safe)});",
        *(boot if "config" in features else []),
        "}",
        "",
        "void board_poll(uint32_t now) {",
        *([f"    {line}" for line in parts.code.polls] or ["    (void)now;"]),
        "}",
        "",
    ]


def write_avr(bf: BoardFile, out_dir: Path) -> list[Path]:
    """Write board_gen.c and board.mk (MCU, baud) into out_dir; returns the files."""
    src = generate_avr(bf)
    out_dir.mkdir(parents=True, exist_ok=True)
    c = out_dir / "board_gen.c"
    c.write_text(src)
    link = bf.board.get("link", {})
    baud = int(link.get("baudrate", 115200))
    mk = out_dir / "board.mk"
    name = c_ident(bf.name, f"{bf.path}: name")  # (a make variable: nothing but a name)
    mk.write_text(
        f"MCU = {bf.mcu}\nBAUD = {baud}\nNAME = {name}\nPARTS = {' '.join(sources(bf))}\n"
        f"DEFS = {' '.join(defines(bf))}\n"
    )
    return [c, mk]


def sources(bf: BoardFile) -> list[str]:
    """The C runtime's sources (src/NAME.c) this board's image holds beyond the core (the
    Makefile's CORE): its drivers', then its features'."""
    out: list[str] = []
    for drv in bf.drivers():
        out += [s for s in DRIVER_SOURCES.get(drv, ()) if s not in out]
    return out + [f for f in FEATURES if f in bf.features]


def defines(bf: BoardFile) -> list[str]:
    """The features' switches (src/features.h): 0 for each one the board file leaves out."""
    return [f"-DML_{f.upper()}={int(f in bf.features)}" for f in FEATURES]
