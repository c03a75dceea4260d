"""What each sensor reads from the body's state: rangers against the walls within their field of
view, the IMU's specific force and turn rate, the compass's field, the GPS's fix with its
wandering error, the battery's voltage.  Pure functions of the state and a seeded random
stream per part, so the same seed and the same commands give the same readings."""

from __future__ import annotations

import itertools
import math
import random
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any, NamedTuple

from .datasheets import G, cep_sigma, imu_sigmas
from .geometry import Matrix, Vec, Wall, apply_t, nearest, rotation, rotation_of
from .motion import Body
from .robot import Part
from .spec import WorldSpec

#: WGS 84: the semi-major axis and the first eccentricity squared
WGS84_A = 6378137.0
WGS84_E2 = 6.69437999014e-3
KNOT_M_S = 1852.0 / 3600.0
#: rays cast across a ranger's field of view (its nearest echo wins); one for a narrow beam
RAYS = 5
NARROW_DEG = 5.0


#: the readings are named tuples, not frozen dataclasses: as immutable, and a frozen dataclass's
#: __init__ (a call a field) took 3 µs of a 25 µs tick at rest
class ImuReading(NamedTuple):
    accel: Vec  #: m/s^2, the chip's axes
    gyro: Vec  #: rad/s
    temperature_c: float


class GpsReading(NamedTuple):
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
    walls: tuple[Wall, ...],
    rng: random.Random,
    noisy: bool,
) -> float | None:
    """Metres to the nearest wall in the part's field of view (``turned``: the angle of what it
    is mounted on), with its noise; None when nothing is within its reach."""
    return reading(beam, cast(part, beam, body, turned, walls), rng, noisy)


def cast(
    part: Part, beam: Beam, body: Body, turned: float, walls: tuple[Wall, ...]
) -> float | None:
    """The nearest wall across a ranger's rays, before its reach and noise: a function of the
    body's x, y and yaw, ``turned`` and the walls alone (world.py keeps it while they stay)."""
    c, s = math.cos(body.yaw), math.sin(body.yaw)
    x, y = body.x + c * part.x - s * part.y, body.y + s * part.x + c * part.y
    looking = body.yaw + part.yaw + turned
    return nearest(x, y, [looking + ray for ray in beam.rays], walls)


def reading(beam: Beam, best: float | None, rng: random.Random, noisy: bool) -> float | None:
    """A ranger's reading of the nearest wall ``best`` (cast()'s), with its noise."""
    draw = rng.gauss(0.0, 1.0)  # (drawn every time: each part's stream stays in step)
    if best is None or best > beam.max_m:
        return None
    sigma = beam.noise_m + beam.noise_fraction * best
    return max(0.0, best + (sigma * draw if noisy else 0.0))


#: the body's rotation and the cosines and sines of its roll and pitch (p, q, r take them)
Attitude = tuple[Matrix, float, float, float, float]


def attitude(body: Body) -> Attitude:
    """The body's rotation (an IMU's and a compass's reading take it: world.py once a read)."""
    cr, sr = math.cos(body.roll), math.sin(body.roll)
    cp, sp = math.cos(body.pitch), math.sin(body.pitch)
    return rotation_of(cr, sr, cp, sp, math.cos(body.yaw), math.sin(body.yaw)), cr, sr, cp, sp


#: what an IMU's readings take of its part that does not change (imu_fixed())
ImuFixed = tuple[Matrix, float, float, Vec, Vec, float, Vec, float]


def imu_fixed(part: Part) -> ImuFixed:
    """What an IMU's readings take of its part that does not change: its mounting's rotation,
    its noise (accelerometer, gyroscope), its biases in SI, its temperature, its place on the
    body (the lever arm) and 0 times its z (a term of the lever arm's cross product with the
    yaw's angular acceleration alone) (looked up once, not every reading)."""
    sa, sg = imu_sigmas(part.fig, int(part.fig["dlpf"]))
    ab = part.triple("accel_bias_mg")
    gb = part.triple("gyro_bias_dps")
    return (rotation(part.roll, part.pitch, part.yaw), sa, sg,
            (ab[0] * 1e-3 * G, ab[1] * 1e-3 * G, ab[2] * 1e-3 * G),
            (math.radians(gb[0]), math.radians(gb[1]), math.radians(gb[2])),
            part.number("temperature_c"), (part.x, part.y, part.z),
            0.0 * part.z)  # fmt: skip


def imu(fixed: ImuFixed, body: Body, rng: random.Random, noisy: bool, att: Attitude) -> ImuReading:
    """The MPU-6050 at its mounting: specific force (gravity up, the body's acceleration and the
    lever arm's) and turn rate, in the chip's axes, with the datasheet's noise; ``fixed``:
    imu_fixed(part), ``att``: attitude(body).  The cross products written out: a tick's hot
    path (the same sums, in the same order)."""
    mount, sa, sg, ab, gb, temperature, (rx, ry, rz), z0 = fixed
    rot, cr, sr, cp, sp = att
    f0, f1, f2 = apply_t(rot, (body.ax, body.ay, G))  # (moving in the plane; gravity a push up)
    yaw_rate, pitch_rate = body.yaw_rate, body.pitch_rate
    w0 = body.roll_rate - yaw_rate * sp  # (p, q, r from the ZYX angles' rates)
    w1 = pitch_rate * cr + yaw_rate * cp * sr
    w2 = -pitch_rate * sr + yaw_rate * cp * cr
    yaw_acc = body.yaw_acc  # (the lever arm's: alpha = (0, 0, yaw_acc); the tilt's left out)
    l0, l1, l2 = z0 - yaw_acc * ry, yaw_acc * rx - z0, 0.0 * ry - 0.0 * rx
    c0, c1, c2 = w1 * rz - w2 * ry, w2 * rx - w0 * rz, w0 * ry - w1 * rx  # (w x r)
    f = (f0 + l0 + (w1 * c2 - w2 * c1), f1 + l1 + (w2 * c0 - w0 * c2),
         f2 + l2 + (w0 * c1 - w1 * c0))  # (centripetal: w x (w x r))  # fmt: skip
    a0, a1, a2 = apply_t(mount, f)
    g0, g1, g2 = apply_t(mount, (w0, w1, w2))
    gauss = rng.gauss
    d = (gauss(0.0, 1.0), gauss(0.0, 1.0), gauss(0.0, 1.0), gauss(0.0, 1.0), gauss(0.0, 1.0),
         gauss(0.0, 1.0))  # fmt: skip
    if not noisy:
        sa = sg = 0.0
    accel = (a0 + ab[0] + sa * d[0], a1 + ab[1] + sa * d[1], a2 + ab[2] + sa * d[2])
    gyro = (g0 + gb[0] + sg * d[3], g1 + gb[1] + sg * d[4], g2 + gb[2] + sg * d[5])
    return ImuReading(accel, gyro, temperature)


def compass_fixed(part: Part, noisy: bool, field_ut: Vec) -> tuple[Matrix, float, Vec]:
    """A compass's mounting's rotation, its noise in gauss and the local field (north, east,
    down in µT) in the world's axes in gauss (looked up once, not every reading)."""
    sigma = part.number("noise_mg") * 1e-3 if noisy else 0.0
    north, east, down = field_ut
    enu = (east / 100.0, north / 100.0, -down / 100.0)  # (1 gauss = 100 µT)
    return rotation(part.roll, part.pitch, part.yaw), sigma, enu


def compass(fixed: tuple[Matrix, float, Vec], rng: random.Random, att: Attitude) -> Vec:
    """The local field in the chip's axes, in gauss, with its noise; ``fixed``:
    compass_fixed(...), ``att``: attitude(body)."""
    mount, sigma, enu = fixed
    b = apply_t(mount, apply_t(att[0], enu))
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
        self._dt, self._k, self._spread = math.nan, 0.0, 0.0  # (step()'s, kept for its dt)

    def step(self, dt: float) -> None:
        if dt != self._dt:  # (a tick's dt is nearly always the last's: its exp and sqrt once)
            k = math.exp(-dt / self.tau) if self.tau > 0 else 0.0
            self._dt, self._k, self._spread = dt, k, self.sigma * math.sqrt(1 - k * k)
        k, spread, gauss = self._k, self._spread, self.rng.gauss
        self.e = [e * k + spread * gauss(0.0, 1.0) for e in self.e]


#: what a fix takes of its part and the site that does not change (gps_fixed())
GpsFixed = tuple[float, float, float, float, float, float, float, float, float, int, float]


def gps_fixed(part: Part, site_deg: tuple[float, float, float], noisy: bool) -> GpsFixed:
    """The antenna's place on the body, the site's origin, the Earth's radii of curvature there
    (metres a radian north, and east), the speed's noise, satellites and HDOP (once)."""
    lat0, lon0, alt0 = site_deg
    phi = math.radians(lat0)
    w = math.sqrt(1 - WGS84_E2 * math.sin(phi) ** 2)
    r_meridian = WGS84_A * (1 - WGS84_E2) / w**3
    r_normal = WGS84_A / w
    spread = part.number("speed_noise_m_s") if noisy else 0.0
    return (part.x, part.y, part.z, lat0, lon0, alt0, r_meridian, r_normal * math.cos(phi),
            spread, int(part.number("satellites")), part.number("hdop"))  # fmt: skip


def gps(fixed: GpsFixed, body: Body, err: GpsError) -> GpsReading:
    """The fix of the antenna (its mounting on the body) around the site's origin."""
    x, y, z, lat0, lon0, alt0, r_meridian, r_east, spread, satellites, hdop = fixed
    c, s = math.cos(body.yaw), math.sin(body.yaw)
    e = err.e
    east = body.x + c * x - s * y + e[0]
    north = body.y + s * x + c * y + e[1]
    up = z + e[2] * err.vertical
    lat = lat0 + math.degrees(north / r_meridian)
    lon = lon0 + math.degrees(east / r_east)
    speed = math.hypot(body.vx, body.vy)
    speed = abs(speed + spread * err.rng.gauss(0.0, 1.0))
    course = math.degrees(math.atan2(body.vx, body.vy)) % 360.0
    return GpsReading(lat, lon, alt0 + up, speed, course, satellites, hdop)


def readers(parts: Iterable[Part], spec: WorldSpec, rng: dict[str, random.Random]) -> list[Any]:
    """The parts a step reads, in the board file's order (the frame's), each as (part, kind,
    its random stream, what its reading takes of it that does not change: worked out once)."""
    site = spec.site
    site_deg = (site.latitude_deg, site.longitude_deg, site.altitude_m)
    out: list[Any] = []
    for p in parts:
        fixed: Any = None
        if p.kind == "ranger":
            fixed = Beam.of(p)
        elif p.kind == "imu":
            fixed = imu_fixed(p)
        elif p.kind == "compass":
            fixed = compass_fixed(p, spec.noise, site.field_ut)
        elif p.kind == "gps":
            fixed = gps_fixed(p, site_deg, spec.noise)
        elif p.kind != "battery":
            continue
        out.append((p, p.kind, rng[p.name], fixed))
    return out


#: a typical Li-ion cell's resting voltage against its charge (ours, rounded from an 18650's
#: published discharge curves at room temperature: not a particular cell's datasheet)
LI_ION_OCV = ((0.0, 3.0), (0.1, 3.45), (0.2, 3.55), (0.3, 3.62), (0.4, 3.68), (0.5, 3.74),
              (0.6, 3.81), (0.7, 3.89), (0.8, 3.97), (0.9, 4.06), (1.0, 4.17))  # fmt: skip


_OCV_SPANS = tuple(itertools.pairwise(LI_ION_OCV))


def cell_volts(charge: float) -> float:
    charge = min(1.0, max(0.0, charge))
    for (c0, v0), (c1, v1) in _OCV_SPANS:
        if charge <= c1:
            return v0 + (v1 - v0) * (charge - c0) / (c1 - c0)
    return LI_ION_OCV[-1][1]
