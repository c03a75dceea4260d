"""How the body moves: two wheels driven by their motors' duty, motions imposed from outside (a
push, a turn, a bump, a tilt), and the walls that stop it.  Pure: a step of ``dt`` seconds in,
the new state out; time is the caller's.

Theory of operation
-------------------
Each wheel's speed follows its motor's duty as a first-order system: towards ``duty x
speed_per_duty`` with the drive's time constant (the motor's and the body's inertia), towards 0
with a tenth of it when the bridge brakes (the windings shorted) and three times it when it
coasts (friction alone); both are ours, not a datasheet's.  The exact solution of that system
over the step gives the angle each wheel turned, and the differential drive's kinematics give
the body's speed and turn rate (a wheel that slips turns without rolling the body by the slip's
fraction).  A motion imposed by hand or by an event moves the body by a fixed displacement over
its duration along a raised cosine (so its acceleration is finite and the IMU feels it).  The
new position is tried against the walls: a body that would touch one stays where it was (a
bump, counted) while its wheels turn on.  Velocities and accelerations are the differences of
positions over the step, so whatever moved the body, the IMU sees it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .geometry import Wall, clear

BRAKE_FACTOR = 0.1  #: a braking motor's time constant, of the drive's
COAST_FACTOR = 3.0  #: a coasting one's


@dataclass
class Wheel:
    speed: float = 0.0  #: rad/s
    angle: float = 0.0  #: rad, turned since the start
    slip: float = 0.0  #: 0..1 of its turning that does not roll the body

    def turn(self, dt: float, duty: float, mode: str, speed_per_duty: float, tau: float) -> float:
        """Run the wheel ``dt`` s at ``duty`` (-1..1) in ``mode`` (drive, coast, brake, ...):
        the angle it turned (rad)."""
        if mode == "brake":
            target, tau = 0.0, tau * BRAKE_FACTOR
        elif mode == "coast" or duty == 0:
            target, tau = 0.0, tau * (COAST_FACTOR if mode == "coast" else 1.0)
        else:
            target = duty * speed_per_duty
        k = math.exp(-dt / tau)
        turned = target * dt + (self.speed - target) * tau * (1 - k)
        self.speed = target + (self.speed - target) * k
        self.angle += turned
        return turned


@dataclass
class Imposed:
    """A motion from outside: the body moved by (dx, dy) m in the world's axes, turned by dyaw
    and tilted by droll, dpitch rad, over ``over`` s from ``start`` s."""

    start: float
    over: float
    dx: float = 0.0
    dy: float = 0.0
    dyaw: float = 0.0
    droll: float = 0.0
    dpitch: float = 0.0

    def share(self, t0: float, t1: float) -> float:
        """The part of the motion done between t0 and t1 (raised cosine: smooth at both ends)."""

        def done(t: float) -> float:
            if self.over <= 0:
                return 1.0 if t >= self.start else 0.0
            u = min(1.0, max(0.0, (t - self.start) / self.over))
            return u - math.sin(2 * math.pi * u) / (2 * math.pi)

        return done(t1) - done(t0)

    def over_at(self, t: float) -> bool:
        return t >= self.start + self.over


@dataclass
class Body:
    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0
    roll: float = 0.0
    pitch: float = 0.0
    vx: float = 0.0  #: world axes, m/s
    vy: float = 0.0
    ax: float = 0.0  #: world axes, m/s^2
    ay: float = 0.0
    yaw_rate: float = 0.0
    yaw_acc: float = 0.0
    roll_rate: float = 0.0
    pitch_rate: float = 0.0
    bumps: int = 0
    against_wall: bool = False

    def place(self, x: float, y: float, yaw: float) -> None:
        """Put the body there at rest (a hand lifts it and sets it down)."""
        self.x, self.y, self.yaw = x, y, yaw
        self.vx = self.vy = self.ax = self.ay = self.yaw_rate = self.yaw_acc = 0.0


@dataclass(frozen=True)
class DriveGeometry:
    wheel_radius: float
    track: float
    speed_per_duty: float
    tau: float


def step(
    body: Body,
    dt: float,
    rolled: tuple[float, float],
    geometry: DriveGeometry,
    imposed: tuple[float, float, float, float, float],
    walls: tuple[Wall, ...],
    radius: float,
) -> None:
    """Move ``body`` over ``dt`` s: ``rolled`` the angles (rad) the left and right wheels turned
    less their slip, ``imposed`` the displacement (dx, dy, dyaw, droll, dpitch) from outside."""
    r, b = geometry.wheel_radius, geometry.track
    ds = r * (rolled[0] + rolled[1]) / 2
    dyaw_drive = r * (rolled[1] - rolled[0]) / b
    dx_i, dy_i, dyaw_i, droll, dpitch = imposed
    heading = body.yaw + dyaw_drive / 2  # (the arc's mean heading)
    nx = body.x + ds * math.cos(heading) + dx_i
    ny = body.y + ds * math.sin(heading) + dy_i
    moved = nx != body.x or ny != body.y
    if moved and not clear(nx, ny, radius, walls):
        if not body.against_wall:
            body.bumps += 1
        body.against_wall = True
        nx, ny = body.x, body.y
    elif moved:
        body.against_wall = False
    vx, vy = (nx - body.x) / dt, (ny - body.y) / dt
    body.ax, body.ay = (vx - body.vx) / dt, (vy - body.vy) / dt
    body.vx, body.vy = vx, vy
    body.x, body.y = nx, ny
    dyaw = dyaw_drive + dyaw_i
    rate = dyaw / dt
    body.yaw_acc = (rate - body.yaw_rate) / dt
    body.yaw_rate = rate
    body.yaw += dyaw
    body.roll_rate, body.pitch_rate = droll / dt, dpitch / dt
    body.roll += droll
    body.pitch += dpitch


def crossings(before: float, after: float, per_rad: float) -> list[tuple[float, int]]:
    """An encoder's edges while its wheel turned from ``before`` to ``after`` rad: (fraction of
    the way, +1 or -1) for each count boundary crossed (``per_rad`` counts a radian)."""
    x0, x1 = before * per_rad + 0.5, after * per_rad + 0.5  # (it starts mid-count)
    if math.floor(x0) == math.floor(x1):
        return []
    span = x1 - x0
    if x1 > x0:
        first, last = math.floor(x0) + 1, math.floor(x1)
        return [((n - x0) / span, 1) for n in range(first, last + 1)]
    first, last = math.floor(x0), math.floor(x1) + 1
    return [((n - x0) / span, -1) for n in range(first, last - 1, -1)]
