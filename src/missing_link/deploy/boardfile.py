"""Board files: one Python dict (``BOARD = {...}``) describing a sensor board - its name, link,
buses and transducers with their drivers - read by the board's firmware (MicroPython imports
it as ``board.py``) and by the host (``flash``, ``gen-firmware``), which parses it as a literal
without running it and checks every entry against the driver it names."""

from __future__ import annotations

import ast
import inspect
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..board.drivers import DRIVERS, driver_class
from ..board.dtypes import DTYPES
from ..board.firmware import RESERVED, describe
from ..descriptors import MAX_NAME, check_unique, read_input_file
from ..errors import ConfigError, DescriptorError
from ..text import did_you_mean, is_token
from .mppins import check_pins

MCUS = ("rp2040", "esp32", "esp32s3", "atmega328p", "atmega2560", "atmega32u4")
AVR_MCUS = ("atmega328p", "atmega2560", "atmega32u4")
BOARD_KEYS = ("name", "model", "mcu", "serial", "fw_version", "link", "buses", "transducers",
              "config_file", "features")  # fmt: skip
#: what an AVR image may leave out (`features`, default all): aligned sampling and timed calls,
#: run-time configuration and its saved record, the board's log (firmware/avr/src/features.h)
FEATURES = ("timing", "config", "log")
#: the keys of each kind of link (board/link.py open_link and signed)
LINK_KEYS = {
    "usb": ("kind", "baudrate"),
    "uart": ("kind", "id", "baudrate", "tx", "rx", "rxbuf"),
    "tcp": ("kind", "port", "dial", "key_file", "boot_file", "replay_file"),
}
#: where a board that dials its daemon connects (board/dial.py): an IPv4 address and a port (a
#: name would be looked up at every dial, and a lookup blocks the firmware's loop)
DIAL = re.compile(r"(25[0-5]|2[0-4]\d|1?\d?\d)(\.(25[0-5]|2[0-4]\d|1?\d?\d)){3}:(\d{1,5})\Z")
LINK_INTS = {"id": (0, 15), "baudrate": (300, 10_000_000), "tx": (0, 255), "rx": (0, 255),
             "rxbuf": (16, 65536), "port": (1, 65535)}  # fmt: skip
BUS_INTS = {"id": (0, 15), "scl": (0, 255), "sda": (0, 255), "freq": (1000, 5_000_000)}
#: a J2A function name, pasted as it stands into the generated C and the function table
IDENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]{0,31}\Z")
#: the firmware's own functions (a2jEcho, a2jAt, ...): no board file entry may take one
BUILTIN_NAME = re.compile(r"a2j[A-Z]")
#: a file on the board's filesystem, in its root: no directories, no way out of the flash stage
FILE_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,63}\Z")
#: property text (board.model, ...): printable ASCII, never the NUL that separates properties
PROPERTY_TEXT = re.compile(r"[ -~]{1,64}\Z")
#: descriptor text (prefix, model, option values): no , or = that separate its fields
DESCRIPTOR_TEXT = re.compile(r"[ -+\--<>-~]{1,64}\Z")


@dataclass(frozen=True)
class BoardFile:
    path: Path
    board: dict[str, Any]

    @property
    def name(self) -> str:
        return str(self.board["name"])

    @property
    def mcu(self) -> str:
        return str(self.board.get("mcu", "rp2040"))

    @property
    def is_avr(self) -> bool:
        return self.mcu in AVR_MCUS

    @property
    def transducers(self) -> list[dict[str, Any]]:
        return list(self.board["transducers"])

    @property
    def features(self) -> tuple[str, ...]:
        """The features the image holds (an AVR's; a MicroPython board has them all)."""
        return tuple(self.board.get("features", FEATURES))

    def drivers(self) -> list[str]:
        return sorted({t["driver"] for t in self.transducers})


def load_board_file(path: str | Path) -> BoardFile:
    """Parse and check a board file; every problem is a ConfigError naming the file and entry."""
    p = Path(path)
    where = str(p)
    try:
        tree = ast.parse(read_input_file(where).decode("utf-8"), filename=where)
    except OSError as e:
        raise ConfigError(f"{where}: cannot read: {e.strerror or e}") from None
    except SyntaxError as e:
        raise ConfigError(f"{where}:{e.lineno}: not Python: {e.msg}") from None
    except ValueError as e:  # not a regular file, too large, not UTF-8, a NUL byte
        raise ConfigError(f"{where}: refused: {e}") from None
    value = None
    for node in tree.body:
        if (
            isinstance(node, ast.Assign)
            and len(node.targets) == 1
            and isinstance(node.targets[0], ast.Name)
            and node.targets[0].id == "BOARD"
        ):
            try:
                value = ast.literal_eval(node.value)
            except ValueError:
                raise ConfigError(
                    f"{where}:{node.lineno}: BOARD must be a literal (dicts, lists, numbers, "
                    "strings): the host reads it without running it"
                ) from None
    if not isinstance(value, dict):
        raise ConfigError(f"{where}: no `BOARD = {{...}}` dict")
    check_board(value, where)
    return BoardFile(p, value)


def check_board(board: dict[str, Any], where: str) -> None:
    """Every key of the board file, its type and its form; ConfigError names the first wrong one.

    A board file is input, not code: what ends up in generated C, in the J2A function table, in
    the descriptor or property text, or on the board's filesystem is checked here by form
    (identifiers, plain file names, text without separators), and every value by type."""
    unknown = sorted(set(board) - set(BOARD_KEYS))
    if unknown:
        raise ConfigError(
            f"{where}: unknown key {unknown[0]!r}{did_you_mean(unknown[0], BOARD_KEYS)} (keys: "
            f"{', '.join(BOARD_KEYS)})"
        )
    name = board.get("name")
    if not isinstance(name, str) or not is_token(name) or len(name) > MAX_NAME:
        raise ConfigError(f"{where}: name must be a topic token like 'front' (got {name!r})")
    mcu = board.get("mcu", "rp2040")
    if mcu not in MCUS:
        raise ConfigError(f"{where}: mcu {mcu!r} is not one of {', '.join(MCUS)}")
    for key in ("model", "serial", "fw_version"):
        if key in board:
            _text(board[key], f"{where}: {key}", PROPERTY_TEXT)
    if "config_file" in board:
        _file_name(board["config_file"], f"{where}: config_file")
    if "features" in board:
        _check_features(board["features"], mcu, where)
    _check_link(board.get("link", {"kind": "usb"}), mcu, where)
    _distinct_files(board, where)
    buses = board.get("buses", {})
    _check_buses(buses, where)
    entries = board.get("transducers")
    if not isinstance(entries, list) or not entries:
        raise ConfigError(f"{where}: transducers must be a non-empty list")
    lines: list[tuple[str, str]] = []
    calls: set[str] = set()
    for k, t in enumerate(entries):
        lines.append(_check_entry(t, k, buses, calls, where))
    try:  # the descriptor as the host will read it from the board: every rule of the host's
        check_unique(lines, where)
    except DescriptorError as e:
        raise ConfigError(str(e)) from None
    if mcu not in AVR_MCUS:  # (an AVR board's pins: avrgen.py, by the C runtime's tables)
        check_pins(board, where)


def _check_features(features: Any, mcu: str, where: str) -> None:
    if mcu not in AVR_MCUS:
        raise ConfigError(f"{where}: features: only an AVR image leaves features out ({mcu!r} "
                          "boards have them all)")  # fmt: skip
    if not isinstance(features, list) or len(set(map(str, features))) != len(features):
        raise ConfigError(f"{where}: features must be a list of distinct names")
    for f in features:
        if f not in FEATURES:
            raise ConfigError(f"{where}: features: {f!r} is not one of {', '.join(FEATURES)}")


def _check_link(link: Any, mcu: str, where: str) -> None:
    if (
        not isinstance(link, dict)
        or not isinstance(link.get("kind", "usb"), str)
        or link.get("kind", "usb") not in LINK_KEYS
    ):
        raise ConfigError(
            f"{where}: link must be {{'kind': 'usb'}}, {{'kind': 'uart', ...}}, "
            "{'kind': 'tcp', 'port': 5000, 'key_file': 'mlkey.bin'} or (a board that dials "
            "its daemon) {'kind': 'tcp', 'dial': '192.168.1.10:7000', 'key_file': 'mlkey.bin'}"
        )
    kind = link.get("kind", "usb")
    if kind == "tcp" and mcu in AVR_MCUS:
        raise ConfigError(f"{where}: the AVR runtime has no network link (tcp)")
    for key, value in link.items():
        at = f"{where}: link {key}"
        if key not in LINK_KEYS[kind]:
            raise ConfigError(
                f"{at}: not a key of a {kind} link{did_you_mean(key, LINK_KEYS[kind])} (keys: "
                f"{', '.join(LINK_KEYS[kind])})"
            )
        if key in ("key_file", "boot_file", "replay_file"):
            _file_name(value, at)
        elif key == "dial":
            _dial(value, link, at)
        elif key in LINK_INTS:
            lo, hi = LINK_INTS[key]
            if not (value is None and key in ("tx", "rx")):
                _integer(value, at, lo, hi)


#: the files the firmware keeps on the board, and the name each has when none is given (None:
#: not kept then); each is written through NAME.tmp (board/store.py, board/link.py)
BOARD_FILES = (("config_file", "mlconfig.bin"), ("key_file", None), ("boot_file", "mlboots.txt"),
               ("replay_file", None))  # fmt: skip


def _distinct_files(board: dict[str, Any], where: str) -> None:
    """No two of the board's files - nor one and another's .tmp - are one file: a key_file
    that is the config_file would be overwritten by the first `config --save`, and the board
    would read a configuration record as its key at the next boot."""
    link = board.get("link", {})
    taken: dict[str, str] = {}
    for key, default in BOARD_FILES:
        if key != "config_file" and link.get("kind") != "tcp":
            continue  # (only a network link keeps files of its own)
        name = (board if key == "config_file" else link).get(key, default)
        if name is None:
            continue
        for file in (name, name + ".tmp"):
            if file in taken:
                raise ConfigError(
                    f"{where}: {key} {name!r} is the file of {taken[file]} (or its .tmp): each "
                    "file on the board must have a name of its own"
                )
            taken[file] = key


def _dial(value: Any, link: dict[str, Any], at: str) -> None:
    m = DIAL.match(value) if isinstance(value, str) else None
    if m is None or not 0 < int(m.group(4)) < 65536:
        raise ConfigError(
            f"{at}: the daemon's IPv4 address and port, like '192.168.1.10:7000' (a name would "
            f"be looked up at every dial, blocking the board), not {value!r}"
        )
    if "port" in link:
        raise ConfigError(f"{at}: a board that dials has no port of its own (drop 'port')")


def _check_buses(buses: Any, where: str) -> None:
    if not isinstance(buses, dict):
        raise ConfigError(f"{where}: buses must be a dict of name -> settings")
    for bus, cfg in buses.items():
        at = f"{where}: bus {bus!r}"
        if not isinstance(bus, str) or not is_token(bus) or not isinstance(cfg, dict):
            raise ConfigError(f"{at}: a bus is 'name': {{'kind': 'i2c', 'id': 0, ...}}")
        for key, value in cfg.items():
            if key == "kind":
                if value != "i2c":
                    raise ConfigError(f"{at}: kind {value!r}: only i2c buses are supported")
            elif key in BUS_INTS:
                _integer(value, f"{at} {key}", *BUS_INTS[key])
            else:
                raise ConfigError(
                    f"{at}: unknown key {key!r}{did_you_mean(key, ['kind', *BUS_INTS])} (keys: "
                    f"kind, {', '.join(BUS_INTS)})"
                )


def _check_entry(
    t: Any, k: int, buses: dict[str, Any], calls: set[str], where: str
) -> tuple[str, str]:
    """One transducer entry; returns (where, its descriptor line) for the host's checks."""
    at = f"{where}: transducers[{k}]"
    if not isinstance(t, dict):
        raise ConfigError(f"{at}: must be a dict")
    tname = t.get("name")
    if not isinstance(tname, str) or not is_token(tname) or len(tname) > MAX_NAME:
        raise ConfigError(f"{at}: name must be a topic token (got {tname!r})")
    at = f"{where}: {tname}"
    tid = t.get("id")
    if isinstance(tid, bool) or not isinstance(tid, int) or not 0 <= tid <= 239:
        raise ConfigError(f"{at}: id must be 0..239 (got {tid!r})")
    drv = t.get("driver")
    if not isinstance(drv, str) or drv not in DRIVERS:
        raise ConfigError(
            f"{at}: driver {drv!r}{did_you_mean(str(drv), DRIVERS)} is not one of "
            f"{', '.join(sorted(DRIVERS))}"
        )
    cls = driver_class(drv)
    _check_reserved(t, at, cls, buses, calls)
    _check_driver_options(t, at, drv, cls)
    return at, describe(t, cls).descriptor_line()


def _check_reserved(
    t: dict[str, Any], at: str, cls: type, buses: dict[str, Any], calls: set[str]
) -> None:
    """The keys every entry may have (board/firmware.py RESERVED), by type and form."""
    if "dtype" in t and t["dtype"] not in DTYPES:
        raise ConfigError(f"{at}: dtype {t['dtype']!r} is not a J2A type")
    if "bus" in t and (not isinstance(t["bus"], str) or t["bus"] not in buses):
        raise ConfigError(f"{at}: bus {t['bus']!r} is not in buses")
    for key in ("prefix", "model"):
        if key in t:
            _text(t[key], f"{at}: {key}", DESCRIPTOR_TEXT)
    if "na" in t:
        _number(t["na"], f"{at}: na", finite=False)
    if "call" in t:
        call = t["call"]
        if not hasattr(cls, "command"):
            raise ConfigError(f"{at}: call: only an actuator has a function to call")
        if not isinstance(call, str) or not IDENT.match(call) or BUILTIN_NAME.match(call):
            raise ConfigError(
                f"{at}: call must be a function name like 'a2j_set_servo' (letters, digits, _; "
                f"at most 32; not a2j + a capital, the firmware's own), not {call!r}"
            )
    if hasattr(cls, "command"):
        call = t.get("call", "a2j_set_" + t["name"])
        if call in calls:
            raise ConfigError(f"{at}: call {call!r} is used twice")
        calls.add(call)
    if "failsafe_ms" in t:
        if not hasattr(cls, "make_safe"):
            raise ConfigError(f"{at}: failsafe_ms: only an actuator with a safe state has one")
        _integer(t["failsafe_ms"], f"{at}: failsafe_ms", 0, 60000)
    options = t.get("options", {})
    if not isinstance(options, dict):
        raise ConfigError(f"{at}: options must be a dict of descriptor options")
    for key, value in options.items():
        if not isinstance(key, str) or not is_token(key):
            raise ConfigError(f"{at}: options: {key!r} is not a key like 'frame_id'")
        if isinstance(value, str):
            _text(value, f"{at}: options {key}", DESCRIPTOR_TEXT)
        else:
            _number(value, f"{at}: options {key}")


def _check_driver_options(t: dict[str, Any], at: str, drv: str, cls: type) -> None:
    """The driver's own keys: its constructor's parameters, typed by their defaults."""
    params = inspect.signature(cls.__init__).parameters  # type: ignore[misc]
    accepted = [n for n in params if n not in ("self", "machine", "clock", "i2c")]
    enums = {key: limits for key, kind, limits, _ro in getattr(cls, "CONFIG", ()) if kind == "enum"}
    for key in t:
        if key in RESERVED:
            continue
        if key not in accepted:
            near = did_you_mean(key, [*accepted, *RESERVED])
            raise ConfigError(
                f"{at}: driver {drv} has no option {key!r}{near} (options: {', '.join(accepted)})"
            )
        _typed(t[key], params[key].default, f"{at}: {key}")
        if key in enums and t[key] not in enums[key]:
            choices = ", ".join(repr(c) for c in enums[key])
            raise ConfigError(f"{at}: {key} is one of {choices}, not {t[key]!r}")
    for key in accepted:
        if params[key].default is inspect.Parameter.empty and key not in t:
            raise ConfigError(f"{at}: driver {drv} needs {key!r}")
    if "i2c" in params and "bus" not in t:
        raise ConfigError(f"{at}: driver {drv} is on I2C: give its bus")


def _typed(value: Any, default: Any, at: str) -> None:
    """A driver option of the type its default has (a pin, with no default, is an integer)."""
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise ConfigError(f"{at}: expected true or false (True/False), got {value!r}")
    elif isinstance(default, str):
        if value is not None:
            _text(value, at, DESCRIPTOR_TEXT)
    elif isinstance(default, (int, float)):  # (a rate of 25 may be 12.5)
        _number(value, at)
    elif not (default is None and value is None):
        _integer(value, at, 0, 255)  # pins and port numbers, with no default or None


def _text(value: Any, at: str, form: re.Pattern[str]) -> None:
    if not isinstance(value, str) or not form.match(value):
        raise ConfigError(
            f"{at}: expected text of at most 64 printable ASCII characters"
            f"{'' if form is PROPERTY_TEXT else ' without , or ='}, got {value!r}"
        )


def _file_name(value: Any, at: str) -> None:
    ok = isinstance(value, str) and FILE_NAME.match(value) and value != "lib"
    if not ok or value.endswith(".py"):  # (the board runs .py files: board.py, main.py, ...)
        raise ConfigError(
            f"{at}: a file in the board's root like 'mlkey.bin' (letters, digits, _ . -; no "
            f"directories, not lib or a .py), not {value!r}"
        )


def _number(value: Any, at: str, finite: bool = True) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{at}: expected a number, got {value!r}")
    if finite and not math.isfinite(value):
        raise ConfigError(f"{at}: expected a finite number, got {value!r}")


def _integer(value: Any, at: str, lo: int, hi: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise ConfigError(f"{at}: expected an integer {lo}..{hi}, got {value!r}")
