"""The robot the world moves, from the board file and the world file: which transducers are its
wheels' motors and encoders, where each ranger, IMU, compass and GPS antenna sits on the body
and which way it looks, what turns with a servo or a stepper, and each part's figures
(datasheets.py, then the world file's).  A world file that names a part the board file does
not have, a figure its kind has not, or a drive that cannot be made, is a WorldFileError."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from .datasheets import DLPF_DEFAULT, KINDS, figures
from .spec import LIMIT, Mount, WorldSpec
from .worldfile import WorldFileError

LEFT_HINTS = ("l", "left")
RIGHT_HINTS = ("r", "right")


@dataclass(frozen=True)
class Part:
    """One transducer the world feeds or reads."""

    name: str
    driver: str
    kind: str
    entry: dict[str, Any]  #: its board file entry
    x: float  #: on the body, metres (REP-103: x forward, y left, z up)
    y: float
    z: float
    roll: float  #: its axes against the body's, rad
    pitch: float
    yaw: float
    on: str  #: the servo or stepper it turns with ("" = the body)
    fig: dict[str, Any] = field(default_factory=dict)

    def number(self, key: str) -> float:
        return float(self.fig[key])

    def triple(self, key: str) -> tuple[float, float, float]:
        a, b, c = self.fig[key]
        return float(a), float(b), float(c)


@dataclass(frozen=True)
class Robot:
    parts: dict[str, Part]
    left_motor: str | None
    right_motor: str | None
    left_encoder: str | None
    right_encoder: str | None

    def of_kind(self, kind: str) -> list[Part]:
        return [p for p in self.parts.values() if p.kind == kind]


def _fail(spec: WorldSpec, key: str, why: str) -> WorldFileError:
    return WorldFileError(f"{spec.source}: {key}: {why}")


def _place(spec: WorldSpec, kind: str, mount: Mount) -> tuple[float, float]:
    if mount.x_m is not None:
        return mount.x_m, mount.y_m
    if kind == "ranger":  # (at the front edge, looking ahead)
        return spec.body_radius_m, mount.y_m
    return 0.0, mount.y_m


def _figure(spec: WorldSpec, where: str, default: Any, value: Any) -> Any:
    """A figure from the world file, checked against its default's shape."""
    if isinstance(default, list):
        if not (isinstance(value, list) and len(value) == len(default)):
            raise _fail(spec, where, f"expected {len(default)} numbers, got {value!r}")
        return [_figure(spec, where, 0.0, v) for v in value]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise _fail(spec, where, f"expected a number, got {value!r}")
    if abs(value) > LIMIT:
        raise _fail(spec, where, f"{value!r} is out of range (-{LIMIT:g}..{LIMIT:g})")
    if value < 0 and not where.endswith(("_c", "_dps", "_mg")):
        raise _fail(spec, where, f"{value!r} must be 0 or more")
    return value


def _figures(spec: WorldSpec, entry: dict[str, Any], kind: str, mount: Mount) -> dict[str, Any]:
    out = figures(entry["driver"], {})
    for key, value in mount.figures.items():
        where = f"parts.{entry['name']}.{key}"
        if key not in out:
            known = ", ".join(["x_m", "y_m", "z_m", "roll_deg", "pitch_deg", "yaw_deg", "on",
                               *out])  # fmt: skip
            raise _fail(spec, where, f"not a key of a {kind} (keys: {known})")
        out[key] = _figure(spec, where, out[key], value)
    if kind == "imu":
        out["dlpf"] = int(entry.get("dlpf", DLPF_DEFAULT))
    return out


def _pick(spec: WorldSpec, parts: dict[str, Part], kind: str, named: str, hints: tuple[str, ...],
          side: int, key: str) -> str | None:  # fmt: skip
    """The drive's left (side 0) or right (1) part of ``kind``: as [drive] names it, else the
    one whose name says the side (a word l, left, r or right between underscores), else the
    first (left) or second (right) in the board file."""
    of_kind = [n for n, p in parts.items() if p.kind == kind]
    if named:
        if named not in of_kind:
            raise _fail(spec, f"drive.{key}", f"{named!r} is not a {kind} of the board file "
                        f"({', '.join(of_kind) or 'it has none'})")  # fmt: skip
        return named
    hinted = [n for n in of_kind if set(n.lower().split("_")) & set(hints)]
    if len(hinted) == 1:
        return hinted[0]
    return of_kind[side] if len(of_kind) == 2 else None


def build(spec: WorldSpec, board: dict[str, Any]) -> Robot:
    """The robot of ``board`` (a board file's dict) as ``spec`` mounts it."""
    entries = {t["name"]: t for t in board.get("transducers", [])}
    for name in spec.parts:
        if name not in entries:
            raise _fail(spec, f"parts.{name}", f"no such part in the board file "
                        f"(parts: {', '.join(entries)})")  # fmt: skip
        if entries[name]["driver"] not in KINDS:
            raise _fail(spec, f"parts.{name}", f"the world has nothing to say to a "
                        f"{entries[name]['driver']}")  # fmt: skip
    parts: dict[str, Part] = {}
    for name, entry in entries.items():
        kind = KINDS.get(entry["driver"])
        if kind is None:
            continue
        mount = spec.parts.get(name, Mount())
        x, y = _place(spec, kind, mount)
        parts[name] = Part(
            name, entry["driver"], kind, entry, x, y, mount.z_m, math.radians(mount.roll_deg),
            math.radians(mount.pitch_deg), math.radians(mount.yaw_deg), mount.on,
            _figures(spec, entry, kind, mount),
        )  # fmt: skip
    for p in parts.values():
        if p.on and (p.on not in parts or parts[p.on].kind not in ("servo", "stepper")):
            raise _fail(spec, f"parts.{p.name}.on", f"{p.on!r} is no servo or stepper of the "
                        "board file")  # fmt: skip
    d = spec.drive
    if d.kind == "none":
        return Robot(parts, None, None, None, None)
    lm = _pick(spec, parts, "motor", d.left_motor, LEFT_HINTS, 0, "left_motor")
    rm = _pick(spec, parts, "motor", d.right_motor, RIGHT_HINTS, 1, "right_motor")
    le = _pick(spec, parts, "encoder", d.left_encoder, LEFT_HINTS, 0, "left_encoder")
    re_ = _pick(spec, parts, "encoder", d.right_encoder, RIGHT_HINTS, 1, "right_encoder")
    if lm is not None and lm == rm:
        raise _fail(spec, "drive.right_motor", f"{rm!r} drives the left wheel already")
    if le is not None and le == re_:
        raise _fail(spec, "drive.right_encoder", f"{re_!r} is on the left wheel already")
    if lm is None or rm is None:  # (not two H-bridges: nothing rolls the body)
        lm = rm = None
    return Robot(parts, lm, rm, le, re_)


def counts_per_rev(robot: Robot, spec: WorldSpec, encoder: str) -> float:
    """An encoder's counts a wheel turn: its figure, else the board file's, else [drive]'s."""
    p = robot.parts[encoder]
    given = p.number("counts_per_rev")
    if given > 0:
        return given
    try:
        from_board = float(p.entry.get("counts_per_rev", 0) or 0)
    except (TypeError, ValueError):
        from_board = 0.0
    return from_board if from_board > 0 else spec.drive.counts_per_rev
