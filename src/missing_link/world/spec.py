"""What a world is made of, with every default: the room, the start pose, the body and its drive,
the battery, the site (where on Earth: the GPS's origin and the magnetic field), each part's
mounting and datasheet figures, and events in time.  worldfile.py reads a world file into these;
docs/world.md is their reference (a test holds the two together)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from .geometry import Segment, square_room

#: no number of a world is larger (metres, seconds, degrees, a part's figures): beyond it a
#: reading overflows what its part holds (a place 1e308 m away ended the board: issue 43.1)
LIMIT = 1e6
#: the default room: 10 m x 10 m around the origin, where the robot starts
ROOM_SIDE_M = 10.0


@dataclass(frozen=True)
class Drive:
    """How the actuators move the body: ``differential`` (two H-bridges, a wheel each) or
    ``none`` (the body stays; servos and steppers still turn what is on them)."""

    kind: str = "differential"
    left_motor: str = ""  #: "" = found by name (motor_l, left_motor...) or the first H-bridge
    right_motor: str = ""
    left_encoder: str = ""  #: "" = found by name (wheel_l, left...) or the first encoder
    right_encoder: str = ""
    wheel_radius_m: float = 0.033
    track_m: float = 0.16  #: between the wheels' contact points
    speed_per_duty: float = 15.0  #: wheel rad/s at duty 1, no load (about 0.5 m/s)
    time_constant_s: float = 0.1  #: the motor and body's inertia: 63 % of a speed change
    counts_per_rev: float = 400.0  #: encoder counts (x4) a wheel turn; the board file's first


@dataclass(frozen=True)
class Battery:
    """The pack the motors draw from: its charge falls with the current, its voltage with the
    charge (a Li-ion cell's resting curve) and with the current through its resistance."""

    cells: int = 2
    capacity_ah: float = 2.0
    charge: float = 0.9  #: at the start, 0..1
    internal_ohm: float = 0.15
    idle_a: float = 0.15  #: the board and its sensors
    stall_a: float = 2.0  #: a motor at duty 1 held still
    free_a: float = 0.2  #: a motor at duty 1 turning freely


@dataclass(frozen=True)
class Site:
    """Where the room is: the GPS's origin (the world's (0, 0)), the local magnetic field (World
    Magnetic Model, north east down) and the air's temperature (the speed of sound)."""

    latitude_deg: float = 48.1173
    longitude_deg: float = 11.516667
    altitude_m: float = 545.4
    field_ut: tuple[float, float, float] = (21.2, 1.5, 43.6)
    temperature_c: float = 20.0


@dataclass(frozen=True)
class Mount:
    """One part as the world file says it: where on the body, which way, on which actuator, and
    the figures that override its datasheet's (``figures``: key -> value, checked per kind)."""

    x_m: float | None = None  #: None: the kind's place (rangers at the front edge, others 0)
    y_m: float = 0.0
    z_m: float = 0.0
    roll_deg: float = 0.0
    pitch_deg: float = 0.0
    yaw_deg: float = 0.0
    on: str = ""  #: a servo or stepper it turns with ("" = the body)
    figures: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Event:
    """Something that happens at ``at_s`` simulated seconds from the start (``kind``: push,
    turn, bump, place, tilt, block, fail, slip), with its own keys in ``args``."""

    at_s: float
    kind: str
    args: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class WorldSpec:
    seed: int | None = None  #: None: the board's --seed (0)
    tick_ms: float = 10.0
    noise: bool = True
    walls: tuple[Segment, ...] = tuple(square_room(ROOM_SIDE_M))
    start: tuple[float, float, float] = (0.0, 0.0, 0.0)  #: x m, y m, yaw rad
    body_radius_m: float = 0.12
    drive: Drive = Drive()
    battery: Battery = Battery()
    site: Site = Site()
    parts: dict[str, Mount] = field(default_factory=dict)
    events: tuple[Event, ...] = ()
    source: str = "the default world"  #: the file it came from, for errors
