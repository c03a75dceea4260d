"""A world file (TOML) read into a WorldSpec, every key checked: an unknown key, a wrong type or a
value out of range is a WorldFileError naming the file and the key, in one line.  The text comes
in (the shell reads the file); nothing here opens one.  docs/world.md has every key with its
default; what is not given is spec.py's default."""

from __future__ import annotations

import math
import tomllib
from dataclasses import fields, replace
from typing import Any

from ..errors import ConfigError
from .geometry import Segment
from .spec import LIMIT, Battery, Drive, Event, Mount, Site, WorldSpec

#: event kind -> its keys (besides at_s and kind) and their defaults (None: required)
EVENTS: dict[str, dict[str, Any]] = {
    "push": {"dx_m": 0.0, "dy_m": 0.0, "over_s": 0.5},
    "turn": {"deg": None, "over_s": 0.5},
    "bump": {"dx_m": -0.01, "dy_m": 0.0, "over_s": 0.02},
    "place": {"x_m": None, "y_m": None, "yaw_deg": 0.0},
    "tilt": {"roll_deg": 0.0, "pitch_deg": 0.0, "over_s": 0.5},
    "block": {"part": None, "distance_m": 0.05, "for_s": 0.0},
    "fail": {"part": None, "mode": "silent", "for_s": 0.0},
    "slip": {"part": None, "fraction": 1.0, "for_s": 0.0},
}
FAIL_MODES = ("silent", "stuck")
TOP = ("world", "room", "start", "body", "drive", "battery", "site", "parts", "events")
MOUNT_KEYS = ("x_m", "y_m", "z_m", "roll_deg", "pitch_deg", "yaw_deg", "on")


class WorldFileError(ConfigError):
    """A world file (or a hand's push) that cannot be used: the message names the file and key."""


class _Reader:
    """Checks values against their defaults' types, naming ``where`` in every error."""

    def __init__(self, source: str) -> None:
        self.source = source

    def fail(self, key: str, why: str) -> WorldFileError:
        return WorldFileError(f"{self.source}: {key}: {why}")

    def table(self, value: Any, key: str) -> dict[str, Any]:
        if not isinstance(value, dict):
            raise self.fail(key, "expected a table")
        return value

    def number(self, value: Any, key: str, lo: float = -math.inf, hi: float = math.inf) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.fail(key, f"expected a number, got {value!r}")
        v = float(value)
        lo, hi = max(lo, -LIMIT), min(hi, LIMIT)
        if not (math.isfinite(v) and lo <= v <= hi):
            bounds = f"{lo:g}..{hi:g}"
            raise self.fail(key, f"{v:g} is out of range ({bounds})")
        return v

    def positive(self, value: Any, key: str) -> float:
        v = self.number(value, key)
        if v <= 0:
            raise self.fail(key, f"{v:g} must be above 0")
        return v

    def like(self, default: Any, value: Any, key: str) -> Any:
        """``value`` as the type of ``default`` (bool, int, float, str, a list of numbers)."""
        if isinstance(default, bool):
            if not isinstance(value, bool):
                raise self.fail(key, f"expected true or false, got {value!r}")
            return value
        if isinstance(default, int):
            if isinstance(value, bool) or not isinstance(value, int):
                raise self.fail(key, f"expected a whole number, got {value!r}")
            return value
        if isinstance(default, float):
            return self.number(value, key)
        if isinstance(default, str):
            if not isinstance(value, str):
                raise self.fail(key, f"expected a string, got {value!r}")
            return value
        if isinstance(default, (list, tuple)):
            if not isinstance(value, list) or len(value) != len(default):
                raise self.fail(key, f"expected {len(default)} numbers, got {value!r}")
            return tuple(self.number(v, key) for v in value)
        raise self.fail(key, "cannot be set")  # (a default of None: set in its own code)

    def known(self, given: dict[str, Any], keys: Any, where: str) -> None:
        for key in given:
            if key not in keys:
                raise self.fail(f"{where}{key}", f"unknown key (keys: {', '.join(keys)})")

    def dataclass_table(self, cls: Any, given: Any, where: str) -> Any:
        """A frozen dataclass from a table of its fields' names, each like its default."""
        table = self.table(given, where.rstrip("."))
        base = cls()
        names = [f.name for f in fields(cls)]
        self.known(table, names, where)
        return replace(base, **{k: self.like(getattr(base, k), v, where + k) for k, v in
                                table.items()})  # fmt: skip


def parse(text: str, source: str) -> WorldSpec:
    """The world file's text (``source``: its name, for errors) as a WorldSpec."""
    r = _Reader(source)
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise WorldFileError(f"{source}: not TOML: {e}") from None
    except RecursionError:  # (tomllib reads nested arrays and tables by recursion)
        raise WorldFileError(f"{source}: not TOML: nested too deep") from None
    r.known(doc, TOP, "")
    spec = WorldSpec(source=source)
    spec = _world(r, doc.get("world", {}), spec)
    if "room" in doc:
        spec = replace(spec, walls=_walls(r, r.table(doc["room"], "room")))
    if "start" in doc:
        spec = replace(spec, start=_start(r, r.table(doc["start"], "start")))
    if "body" in doc:
        body = r.table(doc["body"], "body")
        r.known(body, ("radius_m",), "body.")
        if "radius_m" in body:
            spec = replace(spec, body_radius_m=r.positive(body["radius_m"], "body.radius_m"))
    spec = replace(spec, drive=_drive(r, doc.get("drive", {})))
    spec = replace(spec, battery=_battery(r, doc.get("battery", {})))
    spec = replace(spec, site=_site(r, doc.get("site", {})))
    parts = r.table(doc.get("parts", {}), "parts")
    spec = replace(spec, parts={k: _mount(r, v, f"parts.{k}.") for k, v in parts.items()})
    events = doc.get("events", [])
    if not isinstance(events, list):
        raise r.fail("events", "expected [[events]] tables")
    spec = replace(spec, events=tuple(_event(r, e, f"events[{i}].") for i, e in
                                      enumerate(events)))  # fmt: skip
    return spec


def _world(r: _Reader, given: Any, spec: WorldSpec) -> WorldSpec:
    table = r.table(given, "world")
    r.known(table, ("seed", "tick_ms", "noise"), "world.")
    if "seed" in table:
        spec = replace(spec, seed=r.like(0, table["seed"], "world.seed"))
    if "tick_ms" in table:
        spec = replace(spec, tick_ms=r.number(table["tick_ms"], "world.tick_ms", 1.0, 100.0))
    if "noise" in table:
        spec = replace(spec, noise=r.like(True, table["noise"], "world.noise"))
    return spec


def _walls(r: _Reader, room: dict[str, Any]) -> tuple[Segment, ...]:
    r.known(room, ("walls",), "room.")
    walls = room.get("walls", [])
    if not isinstance(walls, list):
        raise r.fail("room.walls", "expected a list of [[x1, y1], [x2, y2]]")
    out: list[Segment] = []
    for i, w in enumerate(walls):
        key = f"room.walls[{i}]"
        ok = isinstance(w, list) and len(w) == 2
        ok = ok and all(isinstance(p, list) and len(p) == 2 for p in w)
        if not ok:
            raise r.fail(key, f"expected [[x1, y1], [x2, y2]] in metres, got {w!r}")
        (x1, y1), (x2, y2) = ((r.number(c, key) for c in p) for p in w)
        if (x1, y1) == (x2, y2):
            raise r.fail(key, "a wall needs two different ends")
        out.append(((x1, y1), (x2, y2)))
    return tuple(out)


def _start(r: _Reader, start: dict[str, Any]) -> tuple[float, float, float]:
    r.known(start, ("x_m", "y_m", "yaw_deg"), "start.")
    x = r.number(start.get("x_m", 0.0), "start.x_m")
    y = r.number(start.get("y_m", 0.0), "start.y_m")
    return x, y, math.radians(r.number(start.get("yaw_deg", 0.0), "start.yaw_deg"))


def _drive(r: _Reader, given: Any) -> Drive:
    d: Drive = r.dataclass_table(Drive, given, "drive.")
    if d.kind not in ("differential", "none"):
        raise r.fail("drive.kind", f"{d.kind!r}: differential or none")
    for key in ("wheel_radius_m", "track_m", "speed_per_duty", "time_constant_s",
                "counts_per_rev"):  # fmt: skip
        r.positive(getattr(d, key), "drive." + key)
    return d


def _battery(r: _Reader, given: Any) -> Battery:
    b: Battery = r.dataclass_table(Battery, given, "battery.")
    if not 1 <= b.cells <= 100:
        raise r.fail("battery.cells", f"{b.cells}: 1..100")
    r.number(b.charge, "battery.charge", 0.0, 1.0)
    r.positive(b.capacity_ah, "battery.capacity_ah")
    for key in ("internal_ohm", "idle_a", "stall_a", "free_a"):
        r.number(getattr(b, key), "battery." + key, 0.0)
    return b


def _site(r: _Reader, given: Any) -> Site:
    s: Site = r.dataclass_table(Site, given, "site.")
    r.number(s.latitude_deg, "site.latitude_deg", -90.0, 90.0)
    r.number(s.longitude_deg, "site.longitude_deg", -180.0, 180.0)
    return s


def _mount(r: _Reader, given: Any, where: str) -> Mount:
    table = r.table(given, where.rstrip("."))
    plain = {k: v for k, v in table.items() if k in MOUNT_KEYS}
    figures = {k: v for k, v in table.items() if k not in MOUNT_KEYS}
    base = Mount()
    values = {}
    for k, v in plain.items():
        default = 0.0 if k == "x_m" else getattr(base, k)
        values[k] = r.like(default, v, where + k)
    return replace(base, figures=figures, **values)


def _event(r: _Reader, given: Any, where: str) -> Event:
    table = r.table(given, where.rstrip("."))
    kind = table.get("kind")
    if kind not in EVENTS:
        raise r.fail(where + "kind", f"{kind!r}: one of {', '.join(EVENTS)}")
    if "at_s" not in table:
        raise r.fail(where + "at_s", "when it happens (simulated s from the start) is missing")
    at = r.number(table["at_s"], where + "at_s", 0.0)
    keys = EVENTS[kind]
    rest = {k: v for k, v in table.items() if k not in ("at_s", "kind")}
    r.known(rest, list(keys), where)
    return Event(at, kind, event_args(r, kind, rest, where))


def event_args(r: _Reader, kind: str, given: dict[str, Any], where: str) -> dict[str, Any]:
    """An event's (or a hand's push's) arguments checked, its defaults filled in."""
    out: dict[str, Any] = {}
    for key, default in EVENTS[kind].items():
        if key not in given:
            if default is None:
                raise r.fail(where + key, f"a {kind} needs {key}")
            out[key] = default
        elif key in ("part", "mode"):
            out[key] = r.like("", given[key], where + key)
        else:
            lo = 0.0 if key in ("for_s", "distance_m", "fraction", "over_s") else -math.inf
            out[key] = r.number(given[key], where + key, lo, 1.0 if key == "fraction" else math.inf)
    if out.get("mode", "silent") not in FAIL_MODES:
        raise r.fail(where + "mode", f"{out['mode']!r}: one of {', '.join(FAIL_MODES)}")
    return out


def hand(kind: str, given: dict[str, Any]) -> dict[str, Any]:
    """A push by hand (``missing-link world URL KIND ...``) checked as an event's keys."""
    r = _Reader("world")
    if kind not in EVENTS:
        raise r.fail("verb", f"{kind!r}: one of {', '.join(EVENTS)}")
    r.known(given, list(EVENTS[kind]), f"{kind} ")
    return event_args(r, kind, given, f"{kind} ")
