"""What each sensor reads from the body's state: rangers against the walls within their field of
view, the IMU's specific force and turn rate, the compass's field, the GPS's fix with its
wandering error, the battery's voltage.  Pure functions of the state and a seeded random
stream per part, so the same seed and the same commands give the same readings."""

from __future__ import annotations

import itertools
import math
import random
from dataclasses import dataclass
from typing import Any

from .datasheets import G, cep_sigma, imu_sigmas
from .geometry import Segment, Vec, apply_t, body_rates, cross, nearest, rotation
from .motion import Body
from .robot import Part

#: WGS 84: the semi-major axis and the first eccentricity squared
WGS84_A = 6378137.0
WGS84_E2 = 6.69437999014e-3
KNOT_M_S = 1852.0 / 3600.0
#: rays cast across a ranger's field of view (its nearest echo wins); one for a narrow beam
RAYS = 5
NARROW_DEG = 5.0


@dataclass(frozen=True)
class ImuReading:
    accel: Vec  #: m/s^2, the chip's axes
    gyro: Vec  #: rad/s
    temperature_c: float


@dataclass(frozen=True)
class GpsReading:
    latitude_deg: float
    longitude_deg: float
    altitude_m: float
    speed_m_s: float
    course_deg: float  #: over ground, true, 0..360
    satellites: int
    hdop: float


@dataclass(frozen=True)
class Beam:
    """A ranger's figures, once: the directions it looks in across its field of view (rad, from
    its axis; one for a narrow beam), its noise and its reach."""

    rays: tuple[float, ...]
    noise_m: float
    noise_fraction: float
    max_m: float

    @classmethod
    def of(cls, part: Part) -> Beam:
        fov = math.radians(part.number("field_of_view_deg"))
        n = 1 if math.degrees(fov) <= NARROW_DEG else RAYS
        rays = (0.0,) if n == 1 else tuple(-fov / 2 + fov * i / (n - 1) for i in range(n))
        return cls(rays, part.number("noise_m"), part.number("noise_fraction"),
                   part.number("max_m"))  # fmt: skip


def ranger(
    part: Part,
    beam: Beam,
    body: Body,
    turned: float,
    walls: list[Segment],
    rng: random.Random,
    noisy: bool,
) -> float | None:
    """Metres to the nearest wall in the part's field of view (``turned``: the angle of what it
    is mounted on), with its noise; None when nothing is within its reach."""
    return reading(beam, cast(part, beam, body, turned, walls), rng, noisy)


def cast(part: Part, beam: Beam, body: Body, turned: float, walls: list[Segment]) -> float | None:
    """The nearest wall across a ranger's rays, before its reach and noise: a function of the
    body's x, y and yaw, ``turned`` and the walls alone (world.py keeps it while they stay)."""
    c, s = math.cos(body.yaw), math.sin(body.yaw)
    origin = (body.x + c * part.x - s * part.y, body.y + s * part.x + c * part.y)
    looking = body.yaw + part.yaw + turned
    best: float | None = None
    for ray in beam.rays:
        d = nearest(origin, looking + ray, walls)
        if d is not None and (best is None or d < best):
            best = d
    return best


def reading(beam: Beam, best: float | None, rng: random.Random, noisy: bool) -> float | None:
    """A ranger's reading of the nearest wall ``best`` (cast()'s), with its noise."""
    draw = rng.gauss(0.0, 1.0)  # (drawn every time: each part's stream stays in step)
    if best is None or best > beam.max_m:
        return None
    sigma = beam.noise_m + beam.noise_fraction * best
    return max(0.0, best + (sigma * draw if noisy else 0.0))


def attitude(body: Body) -> tuple[Vec, Vec, Vec]:
    """The body's rotation (an IMU's and a compass's reading take it: world.py once a read)."""
    return rotation(body.roll, body.pitch, body.yaw)


def imu_fixed(part: Part) -> tuple[Any, float, float, Vec, Vec, float]:
    """What an IMU's readings take of its part that does not change: its mounting's rotation,
    its noise (accelerometer, gyroscope), its biases in SI and its temperature (looked up once,
    not every reading)."""
    sa, sg = imu_sigmas(part.fig, int(part.fig["dlpf"]))
    ab = part.triple("accel_bias_mg")
    gb = part.triple("gyro_bias_dps")
    return (rotation(part.roll, part.pitch, part.yaw), sa, sg,
            (ab[0] * 1e-3 * G, ab[1] * 1e-3 * G, ab[2] * 1e-3 * G),
            (math.radians(gb[0]), math.radians(gb[1]), math.radians(gb[2])),
            part.number("temperature_c"))  # fmt: skip


def imu(
    part: Part, body: Body, rng: random.Random, noisy: bool, fixed: Any = None, att: Any = None
) -> ImuReading:
    """The MPU-6050 at its mounting: specific force (gravity up, the body's acceleration and the
    lever arm's) and turn rate, in the chip's axes, with the datasheet's noise; ``fixed``:
    imu_fixed(part), ``att``: attitude(body), when the caller keeps them."""
    mount, sa, sg, ab, gb, temperature = fixed or imu_fixed(part)
    world_f = (body.ax, body.ay, G)  # (the body moves in the plane; gravity as a push up)
    f = apply_t(att or attitude(body), world_f)
    w = body_rates(body.roll, body.pitch, body.roll_rate, body.pitch_rate, body.yaw_rate)
    r = (part.x, part.y, part.z)
    alpha = (0.0, 0.0, body.yaw_acc)  # (the tilt's own angular acceleration is left out)
    lever = cross(alpha, r)
    centripetal = cross(w, cross(w, r))
    f = (f[0] + lever[0] + centripetal[0], f[1] + lever[1] + centripetal[1],
         f[2] + lever[2] + centripetal[2])  # fmt: skip
    f, w = apply_t(mount, f), apply_t(mount, w)
    draws = [rng.gauss(0.0, 1.0) for _ in range(6)]
    if not noisy:
        sa = sg = 0.0
    accel = tuple(f[i] + ab[i] + sa * draws[i] for i in range(3))
    gyro = tuple(w[i] + gb[i] + sg * draws[3 + i] for i in range(3))
    return ImuReading(accel, gyro, temperature)  # type: ignore[arg-type]


def compass_fixed(part: Part, noisy: bool) -> tuple[Any, float]:
    """A compass's mounting's rotation and its noise in gauss (looked up once, not every
    reading)."""
    sigma = part.number("noise_mg") * 1e-3 if noisy else 0.0
    return rotation(part.roll, part.pitch, part.yaw), sigma


def compass(
    part: Part,
    body: Body,
    field_ut: Vec,
    rng: random.Random,
    noisy: bool,
    fixed: Any = None,
    att: Any = None,
) -> Vec:
    """The local field (north, east, down in µT) in the chip's axes, in gauss, with its noise;
    ``fixed``: compass_fixed(part, noisy), ``att``: attitude(body), when the caller keeps them."""
    mount, sigma = fixed or compass_fixed(part, noisy)
    north, east, down = field_ut
    enu = (east / 100.0, north / 100.0, -down / 100.0)  # (1 gauss = 100 µT)
    b = apply_t(mount, apply_t(att or attitude(body), enu))
    return (b[0] + sigma * rng.gauss(0.0, 1.0), b[1] + sigma * rng.gauss(0.0, 1.0),
            b[2] + sigma * rng.gauss(0.0, 1.0))  # fmt: skip


class GpsError:
    """A receiver's position error: a first-order Gauss-Markov process per axis (east, north,
    up) with the part's CEP as its spread and its correlation time, stepped once a tick."""

    def __init__(self, part: Part, rng: random.Random, noisy: bool) -> None:
        self.sigma = cep_sigma(part.number("cep_m")) if noisy else 0.0
        self.vertical = part.number("vertical_factor")
        self.tau = part.number("error_tau_s")
        self.rng = rng
        self.e = [self.sigma * rng.gauss(0.0, 1.0) for _ in range(3)]

    def step(self, dt: float) -> None:
        k = math.exp(-dt / self.tau) if self.tau > 0 else 0.0
        spread = self.sigma * math.sqrt(1 - k * k)
        self.e = [e * k + spread * self.rng.gauss(0.0, 1.0) for e in self.e]


def gps(
    part: Part, body: Body, site_deg: tuple[float, float, float], err: GpsError, noisy: bool
) -> GpsReading:
    """The fix of the antenna (its mounting on the body) around the site's origin."""
    c, s = math.cos(body.yaw), math.sin(body.yaw)
    east = body.x + c * part.x - s * part.y + err.e[0]
    north = body.y + s * part.x + c * part.y + err.e[1]
    up = part.z + err.e[2] * err.vertical
    lat0, lon0, alt0 = site_deg
    phi = math.radians(lat0)
    w = math.sqrt(1 - WGS84_E2 * math.sin(phi) ** 2)
    r_meridian = WGS84_A * (1 - WGS84_E2) / w**3
    r_normal = WGS84_A / w
    lat = lat0 + math.degrees(north / r_meridian)
    lon = lon0 + math.degrees(east / (r_normal * math.cos(phi)))
    speed = math.hypot(body.vx, body.vy)
    spread = part.number("speed_noise_m_s") if noisy else 0.0
    speed = abs(speed + spread * err.rng.gauss(0.0, 1.0))
    course = math.degrees(math.atan2(body.vx, body.vy)) % 360.0
    return GpsReading(lat, lon, alt0 + up, speed, course, int(part.number("satellites")),
                      part.number("hdop"))  # fmt: skip


#: a typical Li-ion cell's resting voltage against its charge (ours, rounded from an 18650's
#: published discharge curves at room temperature: not a particular cell's datasheet)
LI_ION_OCV = ((0.0, 3.0), (0.1, 3.45), (0.2, 3.55), (0.3, 3.62), (0.4, 3.68), (0.5, 3.74),
              (0.6, 3.81), (0.7, 3.89), (0.8, 3.97), (0.9, 4.06), (1.0, 4.17))  # fmt: skip


def cell_volts(charge: float) -> float:
    charge = min(1.0, max(0.0, charge))
    for (c0, v0), (c1, v1) in itertools.pairwise(LI_ION_OCV):
        if charge <= c1:
            return v0 + (v1 - v0) * (charge - c0) / (c1 - c0)
    return LI_ION_OCV[-1][1]
