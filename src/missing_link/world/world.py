"""The world a virtual board's robot lives in: its body moved by the board's actuators, in a room
its rangers see, felt by its IMU, compass and GPS, drawing its battery.  Pure: no I/O, no clock
(time comes in as board µs), a seeded random stream per part.

Theory of operation
-------------------
A runtime (virtual/worldlink.py, on CPython, MicroPython or AVR) calls :meth:`World.step`
once a tick (the world file's ``tick_ms``) with the simulation's time and what the board's
actuators do now (:class:`Actuation`: each H-bridge's duty and mode, each servo's pulse, each
stepper's position).  The step first applies what is due (the world file's events, pushes by
hand), then reads every sensor from the state at that time (:class:`Frame`: ranges, IMU, field,
fix, volts; the parts that failed), then moves the world on to the step's end under those
commands (held for the tick, as a sample-and-hold) in equal substeps of about SUBSTEP_US: the
motors turn the wheels (motion.py), the body rolls and meets the walls, the battery drains,
servos and steppers turn at their speed limits, and every encoder edge on the way is put in the
frame with its time, so the runtime delivers each as a pin interrupt when the simulation gets
there.  Readings describe the tick's start and edges its run to the end: nothing the board sees
comes before its cause.  Every part draws its noise every step that reads whatever it reads, so
its random stream, and the run, depend only on the seed, the world file and the commands (and
the times the runtime ticks at: a step that only catches up with a runtime come late reads
nothing, draws nothing).
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass, field, replace
from typing import Any, NamedTuple

from . import motion, sensing
from .geometry import Segment, Vec, clear, prepare
from .motion import Body, DriveGeometry, Imposed, Wheel
from .robot import Robot, build, counts_per_rev
from .sensing import GpsError, GpsReading, ImuReading
from .spec import Event, WorldSpec
from .worldfile import WorldFileError, hand

SUBSTEP_US = 5000
SENSORS = ("ranger", "imu", "compass", "gps", "battery", "encoder")
COAST = (0.0, "coast")  #: a motor the board does not drive
STILL = (0.0, 0.0, 0.0, 0.0, 0.0)  #: nothing imposed from outside


@dataclass
class Actuation:
    """What the board's actuators do now, by transducer name."""

    motors: dict[str, tuple[float, str]] = field(default_factory=dict)  #: duty -1..1, mode
    servos: dict[str, float | None] = field(default_factory=dict)  #: pulse µs (None: limp)
    steppers: dict[str, tuple[int, bool]] = field(default_factory=dict)  #: microsteps, enabled


class Frame(NamedTuple):
    """The sensors at ``t_us`` and the encoders' edges from then to ``until_us`` (a named
    tuple: see sensing.ImuReading)."""

    t_us: int
    until_us: int
    edges: dict[str, list[tuple[int, int]]]  #: encoder -> [(board µs, +1 | -1)]
    ranges: dict[str, float | None]  #: metres (None: nothing in reach)
    imus: dict[str, ImuReading]
    fields: dict[str, Vec]  #: gauss, the chip's axes
    fixes: dict[str, GpsReading]
    volts: dict[str, float]  #: the pack's
    failed: dict[str, str]  #: part -> "silent" (a stuck one reads its last reading here)


#: the most encoder edges a second a world makes (a 2000-count encoder at 6,000 rpm); beyond,
#: a tick's edges ran into the millions (speed_per_duty = 1e6 held the board for good)
MAX_EDGES_S = 200_000


class World:
    """``spec``'s world for ``board`` (a board file's dict), its clock starting at ``start_us``
    (board µs); ``seed`` when the world file names none."""

    def __init__(self, spec: WorldSpec, board: dict[str, Any], start_us: int, seed: int = 0):
        self.spec = spec
        self.robot: Robot = build(spec, board)
        self.seed = spec.seed if spec.seed is not None else seed
        self.t_us = start_us
        self.start_us = start_us
        self.walls: list[Segment] = list(spec.walls)
        self.wall_sums = prepare(self.walls)
        self.body = Body()
        self.body.place(*spec.start)
        if not clear(self.body.x, self.body.y, spec.body_radius_m, self.wall_sums):
            raise WorldFileError(f"{spec.source}: start: the body ({spec.body_radius_m:g} m "
                                 "round) stands in a wall")  # fmt: skip
        d = spec.drive
        self.geometry = DriveGeometry(d.wheel_radius_m, d.track_m, d.speed_per_duty,
                                      d.time_constant_s)  # fmt: skip
        self.wheels = (Wheel(), Wheel())
        encoders = (self.robot.left_encoder, self.robot.right_encoder)
        self.per_rad = {e: counts_per_rev(self.robot, spec, e) / (2 * math.pi)
                        for e in encoders if e}  # fmt: skip
        _edge_rate(spec, self.per_rad.values())
        # a motor mounted mirrored (its board-file entry's "invert": the firmware flips its
        # command) turns its wheel forward when its bridge drives backward; an encoder on a
        # mirrored wheel ("reverse": the firmware flips its count) counts backward going forward
        flips = {"motor": "invert", "encoder": "reverse"}
        self.mirrored = {p.name for p in self.robot.parts.values()
                         if p.kind in flips and p.entry.get(flips[p.kind])}  # fmt: skip
        self.rng = {n: random.Random(f"{self.seed}/{n}") for n in self.robot.parts}
        self.gps_err = {p.name: GpsError(p, self.rng[p.name], spec.noise)
                        for p in self.robot.of_kind("gps")}  # fmt: skip
        self.sensors = sensing.readers(self.robot.parts.values(), spec, self.rng)
        bat = spec.battery  # (a motor's current and the charge's sums: their constants once)
        self.amp_hours_s = 3600 * bat.capacity_ah
        self.stall_extra_a = bat.stall_a - bat.free_a
        # each wheel's (motor, encoder, mirrored motor, encoder's counts a radian, its sign)
        r = self.robot
        self.sides = tuple((m, e or "", m in self.mirrored, self.per_rad.get(e) if e else None,
                            -1 if e in self.mirrored else 1)
                           for m, e in ((r.left_motor, r.left_encoder),
                                        (r.right_motor, r.right_encoder)))  # fmt: skip
        # ranger -> ((x, y, yaw, turned), its cast): a pose the body still has is not cast again
        self.casts: dict[str, tuple[tuple[float, float, float, float], float | None]] = {}
        self.turned = {p.name: 0.0 for p in self.robot.parts.values()
                       if p.kind in ("servo", "stepper")}  # fmt: skip
        self.turning = {n: _turning(self.robot.parts[n]) for n in self.turned}
        self.charge = spec.battery.charge
        self.current = spec.battery.idle_a
        self.imposed: list[Imposed] = []
        self.blocks: dict[str, tuple[float, float | None]] = {}  # ranger -> distance, until s
        self.fails: dict[str, tuple[str, float | None]] = {}  # part -> mode, until s
        self.slips: dict[int, float | None] = {}  # wheel -> until s
        self.held: dict[str, Any] = {}  # a stuck part's last reading
        self.last: dict[str, Any] = {}
        self.queue: list[Event] = sorted(spec.events, key=lambda e: e.at_s)
        for i, e in enumerate(spec.events):
            self._check(e, f"{spec.source}: events[{i}].")

    # ---- time ----
    def now_s(self) -> float:
        return (self.t_us - self.start_us) / 1e6

    def skip(self, us: int) -> None:
        """Stand still for ``us`` of the board's clock: the world's own time (its events, pushes
        under way, the GPS's wander) pauses, nothing moves, reads or draws (a host that stopped
        its board for a while: worldlink.py)."""
        self.t_us += us
        self.start_us += us

    def step(self, until_us: int, act: Actuation, read: bool = True) -> Frame:
        """Read the sensors now (``read``; else the frame has the edges alone), then run the
        world to ``until_us`` under ``act``."""
        t0 = self.t_us
        self._due()
        frame = self._read(t0, max(t0, until_us)) if read else self._unread(t0, until_us)
        t, n = t0, max(1, round((until_us - t0) / SUBSTEP_US))  # (equal ones, SUBSTEP_US or so)
        for k in range(n if until_us > t0 else 0):
            dt_us = (until_us - t0) * (k + 1) // n - (t - t0)
            self._substep(t, dt_us, act, frame.edges)
            t += dt_us
        self.t_us = max(t0, until_us)
        for err in self.gps_err.values():
            err.step((self.t_us - t0) / 1e6)
        return frame

    # ---- what happens, by hand or in the world file ----
    def command(self, kind: str, args: dict[str, Any]) -> None:
        """A push by hand (``missing-link world URL KIND ...``), applied at the next step;
        WorldFileError when it cannot be done."""
        self.queue.insert(0, Event(self.now_s(), kind, self.checked(kind, args)))

    def checked(self, kind: str, args: dict[str, Any]) -> dict[str, Any]:
        """A push's arguments, checked (WorldFileError: one line), not applied."""
        checked = hand(kind, args)
        self._check(Event(self.now_s(), kind, checked), f"world: {kind} ")
        return checked

    # ---- back to an earlier state (a runtime's ticks computed ahead: virtual/worldlink.py) ----
    def snapshot(self) -> tuple[Any, ...]:
        """What changes as the world runs (its random streams' states too), for restore()."""
        return (self.t_us, self.start_us, replace(self.body), [replace(w) for w in self.wheels],
                {n: r.getstate() for n, r in self.rng.items()},
                {n: list(e.e) for n, e in self.gps_err.items()}, dict(self.casts),
                dict(self.turned), self.charge, self.current, list(self.imposed),
                dict(self.blocks), dict(self.fails), dict(self.slips), dict(self.held),
                dict(self.last), list(self.queue))  # fmt: skip

    def restore(self, snap: tuple[Any, ...]) -> None:
        """The world as it was at ``snap`` (snapshot()'s; it may be restored again)."""
        (self.t_us, self.start_us, body, wheels, rngs, gps, casts, turned, self.charge,
         self.current, imposed, blocks, fails, slips, held, last, queue) = snap  # fmt: skip
        self.body = replace(body)
        self.wheels = (replace(wheels[0]), replace(wheels[1]))
        for n, state in rngs.items():
            self.rng[n].setstate(state)
        for n, e in gps.items():
            self.gps_err[n].e = list(e)
        self.casts, self.turned, self.imposed = dict(casts), dict(turned), list(imposed)
        self.blocks, self.fails, self.slips = dict(blocks), dict(fails), dict(slips)
        self.held, self.last, self.queue = dict(held), dict(last), list(queue)

    def _check(self, e: Event, where: str) -> None:
        part = e.args.get("part")
        fit = {"block": ("ranger",), "fail": SENSORS, "slip": ("encoder", "motor")}
        if part is not None:
            p = self.robot.parts.get(str(part))
            if p is None or p.kind not in fit[e.kind]:
                kinds = [n for n, q in self.robot.parts.items() if q.kind in fit[e.kind]]
                raise WorldFileError(f"{where}part: {part!r}: a {e.kind} takes one of "
                                     f"{', '.join(kinds) or 'none on this board'}")  # fmt: skip
            if e.kind == "slip" and self._wheel_of(str(part)) is None:
                raise WorldFileError(f"{where}part: {part!r} is on no wheel of the drive")
        if e.kind == "place":
            at = (float(e.args["x_m"]), float(e.args["y_m"]))
            if not clear(*at, self.spec.body_radius_m, self.wall_sums):
                raise WorldFileError(f"{where}place: ({at[0]:g}, {at[1]:g}) is in a wall")

    def _wheel_of(self, part: str) -> int | None:
        r = self.robot
        if part in (r.left_motor, r.left_encoder):
            return 0
        if part in (r.right_motor, r.right_encoder):
            return 1
        return None

    def _due(self) -> None:
        now = self.now_s()
        while self.queue and self.queue[0].at_s <= now:
            self._apply(self.queue.pop(0), now)
        if self.blocks or self.fails or self.slips:  # (mostly none: not looked through)
            self._over(now)
        if self.imposed:
            self.imposed = [m for m in self.imposed if not m.over_at(now)]

    def _over(self, now: float) -> None:
        """The blocks, failures and slips that are over by ``now`` gone."""
        for name, (_, until) in list(self.blocks.items()):
            if until is not None and now >= until:
                del self.blocks[name]
        for name, (_, until) in list(self.fails.items()):
            if until is not None and now >= until:
                del self.fails[name]
                self.held.pop(name, None)
        for wheel, until in list(self.slips.items()):
            if until is not None and now >= until:
                del self.slips[wheel]
                self.wheels[wheel].slip = 0.0

    def _apply(self, e: Event, now: float) -> None:
        a, b = e.args, self.body
        until = now + float(a["for_s"]) if float(a.get("for_s", 0.0) or 0.0) > 0 else None
        if e.kind in ("push", "bump"):
            c, s = math.cos(b.yaw), math.sin(b.yaw)
            dx, dy = float(a["dx_m"]), float(a["dy_m"])
            self.imposed.append(Imposed(now, float(a["over_s"]), c * dx - s * dy, s * dx + c * dy))
        elif e.kind == "turn":
            self.imposed.append(Imposed(now, float(a["over_s"]), dyaw=math.radians(a["deg"])))
        elif e.kind == "tilt":
            droll = math.radians(a["roll_deg"]) - b.roll
            dpitch = math.radians(a["pitch_deg"]) - b.pitch
            self.imposed.append(Imposed(now, float(a["over_s"]), droll=droll, dpitch=dpitch))
        elif e.kind == "place":
            b.place(float(a["x_m"]), float(a["y_m"]), math.radians(a["yaw_deg"]))
            self.imposed = [m for m in self.imposed if m.dx == m.dy == m.dyaw == 0.0]
        elif e.kind == "block":
            self.blocks[str(a["part"])] = (float(a["distance_m"]), until)
        elif e.kind == "fail":
            self.fails[str(a["part"])] = (str(a["mode"]), until)
            if a["mode"] == "stuck" and a["part"] in self.last:
                self.held[str(a["part"])] = self.last[str(a["part"])]
        elif e.kind == "slip":
            wheel = self._wheel_of(str(a["part"]))
            assert wheel is not None  # (checked when it was made)
            self.wheels[wheel].slip = float(a["fraction"])
            self.slips[wheel] = until

    # ---- the sensors at the step's start ----
    def _read(self, t0: int, until: int) -> Frame:
        b, noisy, held, last = self.body, self.spec.noise, self.held, self.last
        ranges: dict[str, float | None] = {}
        imus: dict[str, ImuReading] = {}
        fields: dict[str, Vec] = {}
        fixes: dict[str, GpsReading] = {}
        volts: dict[str, float] = {}
        att = sensing.attitude(b)  # (the IMU's and the compass's: once)
        for p, kind, rng, fixed in self.sensors:
            name = p.name
            if kind == "ranger":
                got: Any = sensing.reading(fixed, self._cast(p, fixed), rng, noisy)
                if name in self.blocks:
                    got = self.blocks[name][0]
                ranges[name] = got = held.get(name, got)
            elif kind == "imu":
                imus[name] = got = held.get(name, sensing.imu(fixed, b, rng, noisy, att))
            elif kind == "compass":
                fields[name] = got = held.get(name, sensing.compass(fixed, rng, att))
            elif kind == "gps":
                fixes[name] = got = held.get(name, sensing.gps(fixed, b, self.gps_err[name]))
            else:
                volts[name] = got = held.get(name, self.pack_volts())
            last[name] = got
        failed = {n: m for n, (m, _) in self.fails.items() if m == "silent"}
        edges: dict[str, list[tuple[int, int]]] = {e: [] for e in self.per_rad}
        return Frame(t0, until, edges, ranges, imus, fields, fixes, volts, failed)

    def _cast(self, p: Any, beam: sensing.Beam) -> float | None:
        """The ranger's nearest wall (sensing.cast), cast again only when the body or what the
        part is mounted on has moved since its last (at rest, against a wall: the same rays,
        the same sums; its noise is still drawn every read)."""
        b = self.body
        pose = (b.x, b.y, b.yaw, self.turned.get(p.on, 0.0))
        kept = self.casts.get(p.name)
        if kept is not None and kept[0] == pose:
            return kept[1]
        best = sensing.cast(p, beam, b, pose[3], self.wall_sums)
        self.casts[p.name] = (pose, best)
        return best

    def _unread(self, t0: int, until: int) -> Frame:
        edges: dict[str, list[tuple[int, int]]] = {e: [] for e in self.per_rad}
        return Frame(t0, max(t0, until), edges, {}, {}, {}, {}, {}, {})

    def pack_volts(self) -> float:
        bat = self.spec.battery
        return bat.cells * sensing.cell_volts(self.charge) - self.current * bat.internal_ohm

    # ---- the world moves on ----
    def _substep(self, t: int, dt_us: int, act: Actuation, edges: dict[str, Any]) -> None:
        dt = dt_us / 1e6
        g, motors = self.geometry, act.motors
        rolled = [0.0, 0.0]
        current = self.spec.battery.idle_a
        for i, (m, enc, flip, per_rad, back) in enumerate(self.sides):
            duty, mode = motors.get(m, COAST) if m else COAST
            duty = -duty if flip else duty
            wheel = self.wheels[i]
            before = wheel.angle
            turned = wheel.turn(dt, duty, mode, g.speed_per_duty, g.tau) if m else 0.0
            rolled[i] = turned * (1 - wheel.slip)
            current += self._motor_current(duty, wheel.speed)
            if per_rad is not None:
                for frac, d in motion.crossings(before, wheel.angle, per_rad):
                    edges[enc].append((t + max(1, round(frac * dt_us)), d * back))
        imposed = self._imposed(t, dt_us) if self.imposed else STILL
        motion.step(self.body, dt, (rolled[0], rolled[1]), g, imposed, self.wall_sums,
                    self.spec.body_radius_m)  # fmt: skip
        self.current = current
        self.charge = max(0.0, self.charge - current * dt / self.amp_hours_s)
        if self.turning:
            self._turn_parts(dt, act)

    def _imposed(self, t: int, dt_us: int) -> tuple[float, float, float, float, float]:
        """What the motions imposed from outside move the body by in the substep at ``t``."""
        now, after = (t - self.start_us) / 1e6, (t + dt_us - self.start_us) / 1e6
        shares = [(m, m.share(now, after)) for m in self.imposed]
        keys = ("dx", "dy", "dyaw", "droll", "dpitch")
        dx, dy, dyaw, droll, dpitch = (sum(getattr(m, k) * s for m, s in shares) for k in keys)
        return dx, dy, dyaw, droll, dpitch

    def _motor_current(self, duty: float, speed: float) -> float:
        """A motor's current: its free-running current at that duty, and up to its stall
        current as far as the wheel is slower than the duty would turn it unloaded."""
        if duty == 0:
            return 0.0
        free = duty * self.geometry.speed_per_duty
        load = min(1.0, max(0.0, 1 - speed / free))
        return abs(duty) * (self.spec.battery.free_a + self.stall_extra_a * load)

    def _turn_parts(self, dt: float, act: Actuation) -> None:
        for name, (servo, zero, per_unit, speed) in self.turning.items():
            if servo:
                pulse = act.servos.get(name)
                if pulse is None:
                    continue  # (limp: it stays)
                target = (pulse - zero) * per_unit
            else:
                steps, enabled = act.steppers.get(name, (0, False))
                if not enabled:
                    continue  # (no current: the rotor stays where it is)
                target = steps * per_unit
            delta = target - self.turned[name]
            most = speed * dt
            self.turned[name] += max(-most, min(most, delta))

    # ---- for a hand and a test ----
    def state(self) -> dict[str, Any]:
        """Where the robot is and what it does, in SI units (yaw etc. in degrees)."""
        b = self.body
        return {
            "t_s": round(self.now_s(), 6),
            "x_m": b.x, "y_m": b.y, "yaw_deg": math.degrees(b.yaw),
            "roll_deg": math.degrees(b.roll), "pitch_deg": math.degrees(b.pitch),
            "speed_m_s": math.hypot(b.vx, b.vy), "turn_dps": math.degrees(b.yaw_rate),
            "wheels_rad": [w.angle for w in self.wheels],
            "wheels_rad_s": [w.speed for w in self.wheels],
            "bumps": b.bumps, "against_wall": b.against_wall,
            "battery_v": self.pack_volts(), "charge": self.charge,
            "turned_deg": {n: math.degrees(v) for n, v in self.turned.items()},
            "blocked": sorted(self.blocks), "failed": sorted(self.fails),
        }  # fmt: skip


def _edge_rate(spec: WorldSpec, per_rad: Any) -> None:
    """WorldFileError when the drive's fastest wheel makes more than MAX_EDGES_S encoder edges a
    second (each an interrupt a tick delivers)."""
    d = spec.drive
    fastest = d.speed_per_duty * max(per_rad, default=0.0)
    if fastest > MAX_EDGES_S:
        raise WorldFileError(
            f"{spec.source}: drive.speed_per_duty: {d.speed_per_duty:g} rad/s is {fastest:.0f} "
            f"encoder edges/s; at most {MAX_EDGES_S} (a wheel's counts_per_rev x its speed)"
        )


def _turning(p: Any) -> tuple[bool, float, float, float]:
    """A servo's or stepper's (is a servo, zero, rad a unit, top speed rad/s): a servo's angle
    from its pulse (the board file's centre_us and span_us: +-90 degrees, as its driver says),
    a stepper's from its microsteps (steps_per_rev x microsteps a turn)."""
    if p.kind == "servo":
        half = float(p.entry.get("span_us", 1200)) / 2
        return (
            True,
            float(p.entry.get("centre_us", 1500)),
            math.radians(90.0) / half,
            math.radians(p.number("speed_dps")),
        )
    per_rev = int(p.entry.get("steps_per_rev", 200)) * int(p.entry.get("microsteps", 1))
    return False, 0.0, 2 * math.pi / per_rev, 2 * math.pi * p.number("speed_rev_s")
