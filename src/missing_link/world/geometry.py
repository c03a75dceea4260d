"""The world's geometry: REP-103 axes (x forward, y left, z up on the body; x east, y north, z up
in the world), rotations by roll, pitch and yaw (ZYX, as REP-103 and tf2 name them), and rays
against wall segments.  Plain floats and tuples: the world runs a few hundred times a second
and numpy's per-call cost is larger than these sums."""

from __future__ import annotations

import math

Vec = tuple[float, float, float]
Point = tuple[float, float]
Segment = tuple[Point, Point]
Matrix = tuple[Vec, Vec, Vec]


def rotation(roll: float, pitch: float, yaw: float) -> Matrix:
    """The matrix (rows) that turns a vector from the rotated frame into the frame it is rotated
    in: R = Rz(yaw) Ry(pitch) Rx(roll)."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    return rotation_of(cr, sr, cp, sp, math.cos(yaw), math.sin(yaw))


def rotation_of(cr: float, sr: float, cp: float, sp: float, cy: float, sy: float) -> Matrix:
    """rotation()'s matrix from the cosines and sines of its roll, pitch and yaw."""
    return (
        (cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr),
        (sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr),
        (-sp, cp * sr, cp * cr),
    )


def apply(r: tuple[Vec, Vec, Vec], v: Vec) -> Vec:
    """R v."""
    return (
        r[0][0] * v[0] + r[0][1] * v[1] + r[0][2] * v[2],
        r[1][0] * v[0] + r[1][1] * v[1] + r[1][2] * v[2],
        r[2][0] * v[0] + r[2][1] * v[1] + r[2][2] * v[2],
    )


def apply_t(r: tuple[Vec, Vec, Vec], v: Vec) -> Vec:
    """R^T v: a vector of the outer frame seen in the rotated one."""
    return (
        r[0][0] * v[0] + r[1][0] * v[1] + r[2][0] * v[2],
        r[0][1] * v[0] + r[1][1] * v[1] + r[2][1] * v[2],
        r[0][2] * v[0] + r[1][2] * v[1] + r[2][2] * v[2],
    )


def wrap(angle: float) -> float:
    """An angle in (-pi, pi]."""
    a = math.fmod(angle + math.pi, 2 * math.pi)
    if a <= 0:
        a += 2 * math.pi
    return a - math.pi


#: a wall as the world's sums take it, worked out once: (x1, y1, x2 - x1, y2 - y1, its length
#: squared), so a ray or a body against it does no more than the sums of its own position
Wall = tuple[float, float, float, float, float]


def prepare(walls: list[Segment]) -> tuple[Wall, ...]:
    out = []
    for (x1, y1), (x2, y2) in walls:
        ex, ey = x2 - x1, y2 - y1
        out.append((x1, y1, ex, ey, ex * ex + ey * ey))
    return tuple(out)


def nearest(x: float, y: float, directions: list[float], walls: tuple[Wall, ...]) -> float | None:
    """How far the nearest wall is along any of the rays from (x, y) at ``directions`` (rad,
    from +x), or None when none meets one (a ray along a wall does not see it)."""
    best: float | None = None
    offsets = [(x1 - x, y1 - y, ex, ey) for x1, y1, ex, ey, _ in walls]
    for direction in directions:
        dx, dy = math.cos(direction), math.sin(direction)
        for ox, oy, ex, ey in offsets:
            den = dx * ey - dy * ex
            if abs(den) < 1e-12:
                continue
            t = (ox * ey - oy * ex) / den
            if t >= 0 and (best is None or t < best) and 0 <= (ox * dy - oy * dx) / den <= 1:
                best = t
    return best


def clear(x: float, y: float, radius: float, walls: tuple[Wall, ...]) -> bool:
    """Whether a disc of ``radius`` at (x, y) touches no wall (closer than ``radius`` to its
    nearest point)."""
    for x1, y1, ex, ey, length2 in walls:
        if length2 == 0:
            d = math.hypot(x - x1, y - y1)
        else:
            u = ((x - x1) * ex + (y - y1) * ey) / length2
            u = u if u < 1.0 else 1.0  # (max(0, min(1, u)): the wall's nearest point)
            u = u if u > 0.0 else 0.0
            d = math.hypot(x - x1 - u * ex, y - y1 - u * ey)
        if not d >= radius:
            return False
    return True


def square_room(side: float) -> list[Segment]:
    """Four walls of a square of ``side`` metres around the origin, counter-clockwise."""
    h = side / 2
    corners = [(-h, -h), (h, -h), (h, h), (-h, h)]
    return [(corners[i], corners[(i + 1) % 4]) for i in range(4)]
