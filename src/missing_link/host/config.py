"""A board's run-time configuration from the host (spec Part 2.4, docs/configuration.md): its
keys (``a2jConfigKeys``), their values (``a2jConfigGet``), setting several at once, all or none
(``a2jConfigSet``, optionally saved on the board) and the defaults again (``a2jConfigReset``).

Keys are ``<transducer>.<key>``.  What the board sends is untrusted: the key table is parsed
with caps and every line checked, a reply that does not fit the table is a :class:`BoardError`
naming the board; a value the user gives is checked against the table before anything is sent
(:class:`~missing_link.errors.ConfigError`, naming the key and what is allowed), and what the
board itself refuses comes back as :class:`ConfigRefused` with the board's reason.
"""

from __future__ import annotations

import math
import re
import struct
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Protocol

from ..errors import BoardError, ConfigError, FunctionFailed
from ..text import did_you_mean, safe_text
from .link import CallResult


class Calls(Protocol):
    """What the configuration needs of an open board: its public calls (host/board.py)."""

    index: dict[str, int]

    @property
    def name(self) -> str: ...

    @property
    def is_original(self) -> bool: ...

    def call(self, name: str, payload: bytes = b"", timeout: float | None = None) -> CallResult: ...

    def call_ok(self, name: str, payload: bytes = b"", timeout: float | None = None) -> bytes: ...

    def read_many(self, name: str, *, max_bytes: int = ...) -> bytes: ...


KEYS_FN, GET_FN = "a2jConfigKeys", "a2jConfigGet"
SET_FN, RESET_FN = "a2jConfigSet", "a2jConfigReset"
MAX_KEYS_BLOB = 32 * 1024
MAX_KEYS = 255
MAX_PER_SET = 51  #: pairs of [index][4-byte value] in one a2jConfigSet (one frame)
ST_SAVED, ST_LOADED, ST_DIRTY = 1, 2, 4
_NAME = re.compile(r"[a-z][a-z0-9_]*\.[a-z][a-z0-9_]*\Z")
#: a number as text: ASCII digits only, no underscores (float() takes "1_0" and "\u0667")
_NUMBER = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)(e[+-]?\d+)?\Z", re.ASCII)
_TRUE = {"1", "true", "on", "yes"}
_FALSE = {"0", "false", "off", "no"}

Value = bool | int | float | str


class NotConfigurable(BoardError):
    """The board has no run-time configuration (the 2014 firmware, a board built without it)."""


class ConfigRefused(ConfigError):
    """The board refused a configuration (a combination its driver cannot take): nothing
    changed.  The message is the board's reason."""


@dataclass(frozen=True)
class ConfigKey:
    """One key as the board describes it."""

    index: int
    name: str  #: ``<transducer>.<key>``
    kind: str  #: bool, int, float or enum
    default: Value
    lo: float | None = None
    hi: float | None = None
    choices: tuple[str, ...] = ()
    read_only: bool = False

    @property
    def transducer(self) -> str:
        return self.name.split(".", 1)[0]

    @property
    def key(self) -> str:
        return self.name.split(".", 1)[1]

    def allowed(self) -> str:
        """What this key takes, for error messages and ``--verbose``."""
        if self.kind == "bool":
            return "true or false"
        if self.kind == "enum":
            return "one of " + ", ".join(self.choices)
        what = "a whole number" if self.kind == "int" else "a number"
        return f"{what} in {_n(self.lo)}..{_n(self.hi)}"

    def parse(self, given: object) -> Value:
        """A user's value (text, or a Python value) for this key; ConfigError if it is not
        allowed."""
        where = f"{self.name} = {_shown(given)}"
        if self.read_only:
            raise ConfigError(f"{self.name} is read-only (it is {_n(self.default)} on this board)")
        text = str(given).strip().lower() if not isinstance(given, (bool, int, float)) else None
        if self.kind == "bool":
            if isinstance(given, bool):
                return given
            if text in _TRUE or (isinstance(given, int) and given == 1):
                return True
            if text in _FALSE or (isinstance(given, int) and given == 0):
                return False
            raise ConfigError(f"{where}: expected {self.allowed()}")
        if self.kind == "enum":
            wanted = _n(given) if isinstance(given, (int, float)) else str(given).strip()
            if wanted not in self.choices:
                raise ConfigError(f"{where}: expected {self.allowed()}")
            return natural(wanted)
        if text is not None and not _NUMBER.match(text):
            raise ConfigError(f"{where}: expected {self.allowed()}")
        try:
            number = float(given) if text is None else float(text)  # type: ignore[arg-type]
        except (TypeError, ValueError, OverflowError):  # (OverflowError: an int of 400 digits)
            raise ConfigError(f"{where}: expected {self.allowed()}") from None
        if isinstance(given, bool) or not math.isfinite(number):
            raise ConfigError(f"{where}: expected {self.allowed()}")
        if self.kind == "int":
            if number != int(number):
                raise ConfigError(f"{where}: expected {self.allowed()}")
            number = int(number)
        assert self.lo is not None and self.hi is not None
        try:
            inside = _f32(self.lo) <= _f32(number) <= _f32(self.hi)
        except OverflowError:  # (beyond a float32, so beyond every range: 1e308)
            inside = False
        if not inside:
            raise ConfigError(f"{where}: expected {self.allowed()}")
        return number

    def to_wire(self, value: Value) -> bytes:
        if self.kind == "float":
            return struct.pack("<f", float(value))
        if self.kind == "enum":
            return struct.pack("<i", self.choices.index(_n(value)))
        return struct.pack("<i", int(value))

    def from_wire(self, raw: bytes) -> Value:
        if self.kind == "float":
            return _round32(float(struct.unpack("<f", raw)[0]))
        v: int = struct.unpack("<i", raw)[0]
        if self.kind == "bool":
            return v != 0
        if self.kind == "enum":
            return natural(self.choices[v]) if 0 <= v < len(self.choices) else f"?{v}"
        return v


def _shown(given: object) -> str:
    """A user's value for an error message: short, clean, whatever it is."""
    try:
        return safe_text(repr(given), 60)
    except ValueError:  # (an int over Python's digit limit has no repr)
        return f"a {type(given).__name__} too long to show"


def natural(label: str) -> Value:
    """An enum's choice as the value it names: ``"8"`` -> 8, ``"cm"`` -> ``"cm"``."""
    for kind in (int, float):
        try:
            return kind(label)
        except ValueError:
            pass
    return label


def _n(v: object) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return f"{v:g}" if v == v else "nan"
    return str(v)


def _f32(x: float) -> float:
    return float(struct.unpack("<f", struct.pack("<f", x))[0])


def _round32(x: float) -> float:
    """A float32 from the wire as the number it stood for (25.000000002 -> 25.0)."""
    return float(f"{x:.7g}")


def parse_keys(blob: bytes, board: str) -> list[ConfigKey]:
    """The key table of ``a2jConfigKeys``; BoardError naming the board and line if it is bad."""
    if len(blob) > MAX_KEYS_BLOB:
        raise BoardError(board, f"configuration keys: {len(blob)} bytes, over {MAX_KEYS_BLOB}")
    try:
        text = blob.decode("utf-8")
    except UnicodeDecodeError as e:
        raise BoardError(board, f"configuration keys are not UTF-8: {e}") from None
    lines = text.split("\n")
    if not lines or lines[0] != "config/1":
        raise BoardError(board, f"configuration keys: first line {lines[0][:40]!r}, not config/1")
    keys: list[ConfigKey] = []
    for n, line in enumerate(lines[1:], start=2):
        if not line:
            continue
        try:
            keys.append(_parse_line(line, len(keys)))
        except (ValueError, IndexError) as e:
            raise BoardError(board, f"configuration keys line {n}: {e}") from None
    if len(keys) > MAX_KEYS or len({k.name for k in keys}) != len(keys):
        raise BoardError(board, "configuration keys: too many, or a name twice")
    return keys


def _parse_line(line: str, index: int) -> ConfigKey:
    name, kind, default, limits, flags = line.split(";")
    if not _NAME.match(name):
        raise ValueError(f"{name[:40]!r} is not transducer.key")
    ro = flags == "ro"
    if kind == "bool":
        return ConfigKey(index, name, kind, default == "1", read_only=ro)
    if kind == "enum":
        choices = tuple(limits.split("|"))
        if not all(c.isprintable() for c in choices):  # (they reach terminals and faces)
            raise ValueError(f"{name}: an enum choice that is not printable text")
        if not all(choices) or default not in choices:
            raise ValueError(f"{name}: enum {limits!r} with default {default!r}")
        return ConfigKey(index, name, kind, natural(default), choices=choices, read_only=ro)
    if kind not in ("int", "float"):
        raise ValueError(f"{name}: kind {kind!r}")
    lo_text, hi_text = limits.split("..")
    lo, hi = float(lo_text), float(hi_text)
    number = float(default)
    if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
        raise ValueError(f"{name}: limits {limits!r}")
    if not math.isfinite(number):  # (int(inf) raised OverflowError: a board's, or a recording's)
        raise ValueError(f"{name}: default {default[:40]!r}")
    value: Value = int(number) if kind == "int" else number
    return ConfigKey(index, name, kind, value, lo, hi, read_only=ro)


class BoardConfig:
    """The configuration functions of one open board (its public calls only)."""

    def __init__(self, board: Calls) -> None:
        self.board = board
        self._keys: list[ConfigKey] | None = None
        self.state = 0  #: ST_SAVED | ST_LOADED | ST_DIRTY, as of the last read

    @property
    def available(self) -> bool:
        return all(f in self.board.index for f in (KEYS_FN, GET_FN, SET_FN, RESET_FN))

    def _check(self) -> None:
        if not self.available:
            why = "the 2014 firmware" if self.board.is_original else "built without it"
            raise NotConfigurable(
                self.board.name, f"not configurable: no {KEYS_FN} and its functions ({why})"
            )

    def keys(self) -> list[ConfigKey]:
        self._check()
        if self._keys is None:
            blob = self.board.read_many(KEYS_FN, max_bytes=MAX_KEYS_BLOB)
            self._keys = parse_keys(blob, self.board.name)
        return self._keys

    def by_name(self) -> dict[str, ConfigKey]:
        return {k.name: k for k in self.keys()}

    def read(self) -> dict[str, Value]:
        keys = self.keys()
        values: dict[str, Value] = {}
        first = 0
        while first < len(keys):
            p = self.board.call_ok(GET_FN, bytes((first,)))
            if len(p) < 3 or p[0] != first or p[1] != len(keys) or (len(p) - 3) % 4:
                raise BoardError(self.board.name, f"{GET_FN}: a reply that does not fit its keys")
            self.state = p[2]
            got = (len(p) - 3) // 4
            if got == 0:
                raise BoardError(self.board.name, f"{GET_FN}: no values from key {first}")
            for i in range(got):
                if first + i < len(keys):
                    k = keys[first + i]
                    values[k.name] = k.from_wire(p[3 + 4 * i : 7 + 4 * i])
            first += got
        return values

    def check(self, wanted: Mapping[str, object]) -> list[tuple[ConfigKey, Value]]:
        """Every key and value checked against the board's table; ConfigError naming the first
        bad one (nothing is sent then)."""
        table = self.by_name()
        out: list[tuple[ConfigKey, Value]] = []
        for name, given in wanted.items():
            key = table.get(name)
            if key is None:
                near = sorted(k for k in table if k.split(".")[0] == name.split(".")[0])
                if near:
                    hint = f"{name.split('.')[0]} has: {', '.join(near)}"
                else:
                    hint = "transducers: " + ", ".join(
                        dict.fromkeys(k.transducer for k in table.values())
                    )
                near_key = did_you_mean(name, table)
                raise ConfigError(f"{name}: no such key on {self.board.name}{near_key} ({hint})")
            out.append((key, key.parse(given)))
        if len(out) > MAX_PER_SET:
            raise ConfigError(f"{len(out)} keys in one command: at most {MAX_PER_SET}")
        return out

    def configure(self, wanted: Mapping[str, object], save: bool = False) -> dict[str, Value]:
        """Set the keys in ``wanted`` all at once (or none); ``save`` keeps the result on the
        board.  Returns the configuration after it."""
        pairs = self.check(wanted)
        payload = bytes((1 if save else 0,)) + b"".join(
            bytes((k.index,)) + k.to_wire(v) for k, v in pairs
        )
        result = self.board.call(SET_FN, payload)
        self._answer(SET_FN, result.code, result.payload)
        return self.read()

    def reset(self, erase_saved: bool = False) -> dict[str, Value]:
        self._check()
        result = self.board.call(RESET_FN, bytes((1 if erase_saved else 0,)))
        self._answer(RESET_FN, result.code, result.payload)
        return self.read()

    def _answer(self, fn: str, code: int, payload: bytes) -> None:
        reason = payload.decode("utf-8", "replace")[:200]
        if code == 0:
            return
        if code == 0xFF:
            raise ConfigRefused(f"{self.board.name}: refused, nothing changed: {reason}")
        if code == 1:  # applied, not saved
            raise FunctionFailed(self.board.name, fn, code, payload)
        raise BoardError(self.board.name, f"{fn} returned {code:#04x}: {reason}")


def describe_keys(keys: list[ConfigKey], values: Mapping[str, Value]) -> list[dict[str, Any]]:
    """Each key with its value, default and limits (``config --json --verbose``)."""
    return [
        {
            "key": k.name,
            "value": values.get(k.name),
            "default": k.default,
            "kind": k.kind,
            "allowed": k.allowed(),
            "read_only": k.read_only,
        }
        for k in keys
    ]


def actuators_changed(
    keys: list[ConfigKey],
    actuators: set[str],
    now: Mapping[str, Value],
    wanted: Mapping[str, object] | None,
    save: bool = False,
    erase: bool = False,
) -> list[str]:
    """The actuators (transducer names in ``actuators``) whose keys a change would change: a
    set of ``wanted`` (None: a reset to the defaults) against the values ``now``, and with
    ``save`` what the board boots with (an actuator key saved away from its default); with
    ``erase`` (a reset that erases the saved configuration) every actuator with a key it may
    set, since what it boots with may change and the saved values are not read.  Keys of an
    actuator are commands (docs/security.md): a face that may not command it may not change,
    reset or erase them either.  ConfigError for a key or value the table does not take."""
    table = {k.name: k for k in keys}
    after = dict(now)
    if wanted is None:
        after.update({k.name: k.default for k in keys if not k.read_only})
    else:
        for name, given in wanted.items():
            key = table.get(name)
            if key is None:
                raise ConfigError(f"{safe_text(name, 60)}: no such key")
            after[name] = key.parse(given)
    out: list[str] = []
    for k in keys:
        if k.transducer not in actuators or k.transducer in out:
            continue
        moved = not _same(k, now.get(k.name), after.get(k.name)) or (erase and not k.read_only)
        if moved or (save and not _same(k, after.get(k.name), k.default)):
            out.append(k.transducer)
    return out


def _same(k: ConfigKey, a: Value | None, b: Value | None) -> bool:
    """Whether two values of ``k`` are one value on the wire (floats as the board keeps them)."""
    if a is None or b is None:
        return a is b
    try:
        return k.to_wire(a) == k.to_wire(b)
    except (ValueError, TypeError, OverflowError, struct.error):  # (an enum value not a choice)
        return False
