"""Transducer descriptors (spec 2.2): strict parsing of ``transds/1`` and SIF payload decoding."""

from __future__ import annotations

import functools
import math
import re
import struct
import sys
from collections.abc import Callable
from dataclasses import dataclass, field

from .board.dtypes import DTYPES, FLOAT_TYPES, SIF_MAX_PAYLOAD
from .errors import DescriptorError
from .text import clean

HEADER = "transds/1"
NAME_RE = re.compile(r"[a-z][a-z0-9_]*\Z")
MAX_NAME = 64
ROS_TYPE_RE = re.compile(r"[A-Za-z][A-Za-z0-9_]*/msg/[A-Z][A-Za-z0-9]*\Z")
FIELDS = ("name", "id", "prefix", "model", "chan_count", "type", "na")
KNOWN_KEYS = (
    "unit", "scale", "offset", "min", "max", "rate_hz", "kind", "call", "ros", "frame_id",
    "counts_per_rev",
)  # fmt: skip
#: where a float32 ends: a value this large or larger rounds to infinity (FLT_MAX plus half
#: its last step), so FLT_MAX and 3.4028235e38 (its shortest decimal) fit, 3.40282357e38 not
FLOAT32_END = 2.0**128 - 2.0**103
_FLOAT_KEYS = ("scale", "offset", "min", "max", "rate_hz", "counts_per_rev")


@dataclass(frozen=True)
class Transducer:
    """One transducer as a board (or a host-side TOML file) describes it."""

    name: str
    id: int
    prefix: str
    model: str
    chan_count: int
    dtype: str
    na: int | float
    options: dict[str, str] = field(default_factory=dict)
    unknown: dict[str, str] = field(default_factory=dict)  #: keys this host does not know

    @property
    def kind(self) -> str:
        return self.options.get("kind", "sensor")

    @property
    def is_actuator(self) -> bool:
        return self.kind == "actuator"

    @property
    def call(self) -> str | None:
        return self.options.get("call")

    @property
    def unit(self) -> str | None:
        return self.options.get("unit")

    @property
    def scaled(self) -> bool:
        """The raw values are counts of ``scale`` (and ``offset``) in ``unit``."""
        return "scale" in self.options or "offset" in self.options

    def in_unit(self, value: float) -> float:
        """A raw value in the transducer's unit: ``value * scale + offset``."""
        return value * float(self.options.get("scale", 1.0)) + float(self.options.get("offset", 0))

    @property
    def sif_size(self) -> int:
        return self.chan_count * (8 + int(DTYPES[self.dtype][1]))

    @functools.cached_property
    def sif_struct(self) -> struct.Struct:
        return _sif_struct(self.dtype, self.chan_count)

    @functools.cached_property
    def _na_is_nan(self) -> bool:
        return isinstance(self.na, float) and math.isnan(self.na)

    def legal(self, value: object) -> bool:
        """Is ``value`` a command this transducer's type holds (:meth:`refusal`)?"""
        return self.refusal(value) is None

    def refusal(self, value: object) -> str | None:
        """Why ``value`` is no command for this transducer's data type, or None: a float type
        takes a finite number its width holds (a float32 at most 3.4028235e38 in magnitude:
        packing more raised OverflowError), never NaN or an infinity (no actuator acts on
        one); an integer type a whole number within its width and signedness; no type its
        N/A value.  Every face's command meets its type here (docs/security.md)."""
        if isinstance(value, bool):
            value = int(value)
        if self.dtype in FLOAT_TYPES:
            if not isinstance(value, (int, float)):
                return f"{_shown(value)} is not a number"
            if isinstance(value, float) and not math.isfinite(value):
                return f"{value} is not a {self.dtype} command (not finite)"
            if self.dtype == "float" and not -FLOAT32_END < value < FLOAT32_END:
                return f"{_shown(value)} is beyond a float (|x| <= 3.4028235e38)"
            if not -sys.float_info.max <= value <= sys.float_info.max:
                return f"{_shown(value)} is beyond a double"
        else:
            _c, _s, lo, hi = DTYPES[self.dtype]
            if not isinstance(value, int):
                return f"{_shown(value)} is not a whole number ({self.dtype})"
            if not lo <= value <= hi:
                return f"{_shown(value)} is beyond {self.dtype} ({lo}..{hi})"
        if value == self.na:
            return f"{_shown(value)} is the N/A value of {self.name}"
        return None

    def pack_command(self, value: object) -> bytes:
        """``value`` packed as the board takes it, after :meth:`refusal`: a ValueError naming
        the transducer and why, never an OverflowError or a struct.error."""
        why = self.refusal(value)
        if why is not None:
            raise ValueError(f"{self.name}: {why}")
        return self.value_struct().pack(value)

    def value_struct(self) -> struct.Struct:
        return struct.Struct("<" + DTYPES[self.dtype][0])

    def decode_columns(self, payload: bytes) -> tuple[list[int], list[int | float | None]]:
        """SIF payload -> (board_us per channel, value per channel or None for N/A).
        The sample path: the unpacked tuple is split by C-level slicing, not a Python loop."""
        st = self.sif_struct
        if len(payload) != st.size:
            raise ValueError(
                f"{self.name}: SIF of {len(payload)} bytes, expected {st.size} "
                f"({self.chan_count} x (8 + {DTYPES[self.dtype][1]}))"
            )
        flat = st.unpack(payload)
        na = self.na
        raw = flat[1::2]
        if self._na_is_nan:
            values: list[int | float | None] = [None if v != v else v for v in raw]
        elif na in raw:
            values = [None if v == na else v for v in raw]
        else:
            values = list(raw)
        return list(flat[0::2]), values

    def decode(self, payload: bytes) -> list[tuple[int, int | float | None]]:
        """SIF payload -> [(board_us, value or None for N/A)] per channel."""
        stamps, values = self.decode_columns(payload)
        return list(zip(stamps, values, strict=True))

    def line(self) -> str:
        """The descriptor line, as a board would send it."""
        base = [self.name, str(self.id), self.prefix, self.model, str(self.chan_count), self.dtype]
        base.append(_fmt(self.na))
        extra = [f"{k}={v}" for k, v in {**self.options, **self.unknown}.items()]
        return ",".join(base + extra)

    def to_json(self) -> dict[str, object]:
        return {
            "name": self.name,
            "id": self.id,
            "prefix": self.prefix,
            "model": self.model,
            "chan_count": self.chan_count,
            "type": self.dtype,
            "na": self.na if not (isinstance(self.na, float) and math.isnan(self.na)) else "nan",
            "options": dict(self.options),
            "unknown": dict(self.unknown),
        }


_STRUCTS: dict[tuple[str, int], struct.Struct] = {}


def _sif_struct(dtype: str, n: int) -> struct.Struct:
    st = _STRUCTS.get((dtype, n))
    if st is None:
        st = _STRUCTS[(dtype, n)] = struct.Struct("<" + ("Q" + DTYPES[dtype][0]) * n)
    return st


def _shown(value: object) -> str:
    """A value in a refusal: short (a 4,000-digit integer is not repeated whole)."""
    text = repr(value)
    return text if len(text) <= 40 else text[:20] + "..." + f"({len(text)} characters)"


def _fmt(v: int | float) -> str:
    return "nan" if isinstance(v, float) and math.isnan(v) else str(v)


def parse_na(text: str, dtype: str) -> int | float:
    """Parse an N/A value in the type's domain; raises ValueError with the reason."""
    t = text.strip()
    if dtype in FLOAT_TYPES:
        return float(t)
    if dtype == "bool" and t.lower() in ("true", "false"):
        return 1 if t.lower() == "true" else 0
    value = int(t, 0)
    _code, _size, lo, hi = DTYPES[dtype]
    if not lo <= value <= hi:
        raise ValueError(f"{value} is outside {dtype} ({lo}..{hi})")
    return value


def _options(
    fields: list[str], fail: Callable[[str, str], DescriptorError]
) -> tuple[dict[str, str], dict[str, str]]:
    """The optional key=value fields: (known, unknown), each checked as far as it is known."""
    options: dict[str, str] = {}
    unknown: dict[str, str] = {}
    for extra in fields:
        if "=" not in extra:
            raise fail(extra or "(empty)", "optional fields are key=value")
        key, value = (s.strip() for s in extra.split("=", 1))
        target = options if key in KNOWN_KEYS else unknown
        if key in options or key in unknown:
            raise fail(key, "given twice")
        target[key] = value
    for key in _FLOAT_KEYS:
        if key in options:
            try:
                float(options[key])
            except ValueError:
                raise fail(key, f"{options[key]!r} is not a number") from None
    if options.get("kind", "sensor") not in ("sensor", "actuator"):
        raise fail("kind", f"{options['kind']!r} is not sensor or actuator")
    if options.get("kind") == "actuator" and not options.get("call"):
        raise fail("call", "an actuator needs call=<function taking one value>")
    if "ros" in options and not ROS_TYPE_RE.match(options["ros"]):
        raise fail("ros", f"{options['ros']!r} is not a message type like sensor_msgs/msg/Range")
    return options, unknown


def parse_line(line: str, board: str = "board", where: str = "transducer") -> Transducer:
    """One descriptor line; ``where`` names it in errors (e.g. "transds line 3")."""

    def fail(fld: str, why: str) -> DescriptorError:
        return DescriptorError(board, f"{where}, field {fld}: {why} (line: {line!r})")

    def number(fld: str, text: str, lo: int, hi: int, why: str = "") -> int:
        try:
            n = int(text, 0)
        except ValueError:
            raise fail(fld, f"{text!r} is not a number") from None
        if not lo <= n <= hi:
            raise fail(fld, f"{n} outside {lo}..{hi}{why}")
        return n

    # Board text is untrusted: a \r or an escape sequence in a model string must not reach a
    # generated .msg file or a terminal.
    parts = [clean(p).strip() for p in line.split(",")]
    if len(parts) < len(FIELDS):
        raise fail(FIELDS[len(parts)], f"missing; a line needs {len(FIELDS)} fields")
    name, id_s, prefix, model, count_s, dtype, na_s = parts[:7]
    if not NAME_RE.match(name):
        raise fail("name", f"{name!r} is not a topic name ([a-z][a-z0-9_]*)")
    if len(name) > MAX_NAME:
        raise fail("name", f"{len(name)} characters; at most {MAX_NAME} (it names files too)")
    tid = number("id", id_s, 0, 239, " (0xF0.. are error codes)")
    if not prefix:
        raise fail("prefix", "empty")
    if not model:
        raise fail("model", "empty")
    chan_count = number("chan_count", count_s, 1, 255)
    if dtype not in DTYPES:
        raise fail("type", f"{dtype!r} is not one of {', '.join(DTYPES)}")
    try:
        na = parse_na(na_s, dtype)
    except ValueError as e:
        raise fail("na", f"{na_s!r} is not a {dtype} value: {e}") from None
    options, unknown = _options(parts[7:], fail)
    size = chan_count * (8 + DTYPES[dtype][1])
    if size > SIF_MAX_PAYLOAD:
        raise fail(
            "chan_count",
            f"{chan_count} channels of {dtype} need {size} bytes; one SIF carries at most 255",
        )
    return Transducer(name, tid, prefix, model, chan_count, dtype, na, options, unknown)


def msg_name(name: str) -> str:
    """``dist_ir`` -> ``DistIr``: the message type a transducer's name gives (ROS CamelCase)."""
    return "".join(part[:1].upper() + part[1:] for part in name.split("_") if part)


def check_unique(items: list[tuple[str, str]], board: str) -> list[Transducer]:
    """Parse (where, line) pairs; names, ids and the message type names they give must be
    unique (``sonar_1`` and ``sonar1`` would both be ``Sonar1``)."""
    out: list[Transducer] = []
    names: dict[str, str] = {}
    ids: dict[int, str] = {}
    types: dict[str, Transducer] = {}
    for where, line in items:
        t = parse_line(line, board, where)
        if t.name in names:
            raise DescriptorError(
                board, f"{where}, field name: {t.name!r} already on {names[t.name]}"
            )
        other = types.get(msg_name(t.name))
        if other is not None:
            raise DescriptorError(
                board,
                f"{where}, field name: {t.name!r} and {other.name!r} (on {names[other.name]}) "
                f"would share the message type {msg_name(t.name)}; rename one",
            )
        types[msg_name(t.name)] = t
        if t.id in ids:
            raise DescriptorError(board, f"{where}, field id: {t.id} already on {ids[t.id]}")
        # Refer back to the first one briefly: "line 2" or "[[transducer]] #1".
        names[t.name] = ids[t.id] = where.removeprefix("transds ")
        out.append(t)
    return out


def parse_transds(text: str, board: str = "board") -> list[Transducer]:
    """Parse a ``transds/1`` blob; names and ids must be unique."""
    lines = text.replace("\r\n", "\n").split("\n")
    if not lines or lines[0].strip() != HEADER:
        raise DescriptorError(board, f"transds line 1: expected {HEADER!r}, got {lines[0][:40]!r}")
    items = [
        (f"transds line {lineno}", line)
        for lineno, line in enumerate(lines[1:], start=2)
        if line.strip() and not line.lstrip().startswith("#")
    ]
    return check_unique(items, board)


#: the largest file a user hands in as input (descriptors, a daemon or board configuration):
#: far beyond any real one (a board's own descriptor blob is capped at 64 KiB)
MAX_INPUT_FILE = 1 << 20


def read_input_file(path: str, cap: int = MAX_INPUT_FILE) -> bytes:
    """The bytes of a file given as input: a regular file of at most ``cap`` bytes.  A device,
    a FIFO or a larger file is refused before it is read (``/dev/zero`` never ends, a FIFO
    blocks): ValueError saying why; OSError as opening it raises it."""
    import os
    import stat

    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)  # (a FIFO: no wait)
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise ValueError("not a regular file")
        if st.st_size > cap:
            raise ValueError(f"{st.st_size} bytes; an input file has at most {cap}")
        chunks, size = [], 0
        while chunk := os.read(fd, cap + 1 - size):
            chunks.append(chunk)
            size += len(chunk)
            if size > cap:  # (it grew since fstat)
                raise ValueError(f"over {cap} bytes; an input file has at most {cap}")
        return b"".join(chunks)
    finally:
        os.close(fd)


def load_descriptor_file(path: str) -> list[Transducer]:
    """Descriptors given on the host (for original boards): a ``transds/1`` text file, or TOML
    with one ``[[transducer]]`` table per transducer (keys: the seven fields, then options)."""
    import tomllib
    from pathlib import Path

    p = Path(path)
    try:
        raw = read_input_file(path)
    except OSError as e:
        raise DescriptorError(path, f"cannot read descriptor file: {e.strerror}") from e
    except ValueError as e:
        raise DescriptorError(path, f"descriptor file refused: {e}") from None
    if p.suffix != ".toml":
        return parse_transds(raw.decode("utf-8", "replace"), path)
    try:
        doc = tomllib.loads(raw.decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise DescriptorError(path, f"not valid TOML: {e}") from e
    except RecursionError:  # (tomllib recurses per level of nesting)
        raise DescriptorError(path, "not valid TOML: nested too deeply") from None
    tables = doc.get("transducer")
    if not isinstance(tables, list) or not tables:
        raise DescriptorError(path, "expected one or more [[transducer]] tables")
    items: list[tuple[str, str]] = []
    for k, table in enumerate(tables, start=1):
        missing = [
            f
            for f in ("name", "id", "prefix", "model", "chan_count", "type", "na")
            if f not in table
        ]
        if missing:
            raise DescriptorError(
                path,
                f"[[transducer]] #{k} ({table.get('name', '?')}): missing {', '.join(missing)}",
            )
        fields = [str(table[f]) for f in ("name", "id", "prefix", "model", "chan_count", "type")]
        fields.append(
            str(table["na"]).lower() if isinstance(table["na"], bool) else str(table["na"])
        )
        for key, value in table.items():
            if key not in ("name", "id", "prefix", "model", "chan_count", "type", "na"):
                fields.append(f"{key}={value}")
        if any("," in f or "\n" in f for f in fields):
            raise DescriptorError(
                path, f"[[transducer]] #{k}: values must not contain ',' or newlines"
            )
        items.append((f"[[transducer]] #{k}", ",".join(fields)))
    return check_unique(items, path)
