"""The world's geometry: REP-103 axes (x forward, y left, z up on the body; x east, y north, z up
in the world), rotations by roll, pitch and yaw (ZYX, as REP-103 and tf2 name them), and rays
against wall segments.  Plain floats and tuples: the world runs a few hundred times a second
and numpy's per-call cost is larger than these sums."""

from __future__ import annotations

import math

Vec = tuple[float, float, float]
Point = tuple[float, float]
Segment = tuple[Point, Point]


def rotation(roll: float, pitch: float, yaw: float) -> tuple[Vec, Vec, Vec]:
    """The matrix (rows) that turns a vector from the rotated frame into the frame it is rotated
    in: R = Rz(yaw) Ry(pitch) Rx(roll)."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
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


def cross(a: Vec, b: Vec) -> Vec:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def body_rates(roll: float, pitch: float, d_roll: float, d_pitch: float, d_yaw: float) -> Vec:
    """The body's angular velocity (p, q, r) in its own axes from the rates of its ZYX angles."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    return (
        d_roll - d_yaw * sp,
        d_pitch * cr + d_yaw * cp * sr,
        -d_pitch * sr + d_yaw * cp * cr,
    )


def wrap(angle: float) -> float:
    """An angle in (-pi, pi]."""
    a = math.fmod(angle + math.pi, 2 * math.pi)
    if a <= 0:
        a += 2 * math.pi
    return a - math.pi


def ray_hit(origin: Point, direction: float, wall: Segment) -> float | None:
    """How far along the ray from ``origin`` at angle ``direction`` (rad, from +x) it meets the
    segment, or None when it does not."""
    (x1, y1), (x2, y2) = wall
    dx, dy = math.cos(direction), math.sin(direction)
    ex, ey = x2 - x1, y2 - y1
    den = dx * ey - dy * ex
    if abs(den) < 1e-12:  # parallel (a ray along a wall does not see it)
        return None
    ox, oy = x1 - origin[0], y1 - origin[1]
    t = (ox * ey - oy * ex) / den
    u = (ox * dy - oy * dx) / den
    if t < 0 or u < 0 or u > 1:
        return None
    return t


def nearest(origin: Point, direction: float, walls: list[Segment]) -> float | None:
    """The nearest wall along a ray, or None (ray_hit's sums, the ray's direction once)."""
    dx, dy = math.cos(direction), math.sin(direction)
    best: float | None = None
    for (x1, y1), (x2, y2) in walls:
        ex, ey = x2 - x1, y2 - y1
        den = dx * ey - dy * ex
        if abs(den) < 1e-12:
            continue
        ox, oy = x1 - origin[0], y1 - origin[1]
        t = (ox * ey - oy * ex) / den
        u = (ox * dy - oy * dx) / den
        if t >= 0 and 0 <= u <= 1 and (best is None or t < best):
            best = t
    return best


def distance_to_segment(p: Point, wall: Segment) -> float:
    (x1, y1), (x2, y2) = wall
    ex, ey = x2 - x1, y2 - y1
    length2 = ex * ex + ey * ey
    if length2 == 0:
        return math.hypot(p[0] - x1, p[1] - y1)
    u = max(0.0, min(1.0, ((p[0] - x1) * ex + (p[1] - y1) * ey) / length2))
    return math.hypot(p[0] - x1 - u * ex, p[1] - y1 - u * ey)


def clear_of(p: Point, radius: float, walls: list[Segment]) -> bool:
    """Whether a disc of ``radius`` at ``p`` touches no wall."""
    return all(distance_to_segment(p, w) >= radius for w in walls)


def square_room(side: float) -> list[Segment]:
    """Four walls of a square of ``side`` metres around the origin, counter-clockwise."""
    h = side / 2
    corners = [(-h, -h), (h, -h), (h, h), (-h, h)]
    return [(corners[i], corners[(i + 1) % 4]) for i in range(4)]
