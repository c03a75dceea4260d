"""The world beside a virtual board's firmware: missing_link/world's World, fed from the board's
actuators and feeding its sensors, through the simulator's worldfeed.py in small integers, on
whichever runtime runs the firmware (CPython here, MicroPython in node: virtual/mpyboard.py).

Theory of operation
-------------------
A runtime asks :meth:`WorldLink.due_us` when the world next needs it and, once the simulation's
time (the board's clock, never the host's) has got there, calls :meth:`WorldLink.tick` with
that time and the integers :attr:`WorldLink.reads` asked of worldfeed.py (each actuator's state,
read in the simulator).  The tick steps the world (world.py: the sensors now, then on to one
tick later under these commands) and hands back the feed calls that put the sensors' readings
into the devices, and the encoders' edges of the tick ahead with their times, which the runtime
delivers as pin interrupts when its time reaches theirs.  A runtime comes a little late (its
step, its poll, its sleep end after the tick's time): that tick reads the sensors at its own
time and runs the world on to one tick after the runtime's, its edges up to now going at once;
a runtime that comes later than a tick (a busy CPython loop) first runs the world up to its
time without reading, and that stretch's edges go at once too.  That stretch is at most
MAX_CATCHUP_US: a runtime later still (its host stopped it, was suspended, or stalled for
long) finds the world paused for the rest, as if it had stopped with its board (World.skip:
nothing moved, no edge, its events and pushes held), said in the log and counted in its
state (``skips``, ``skipped_s``); integrating a minute's pause at once took 1.4 s of CPU and
57,210 encoder edges on the rover, all delivered at once.

A runtime may ask for the ticks of the next BATCH_US at once (:meth:`WorldLink.ahead`, node
under MicroPython and CPython: a wake-up of the world, its code and data cold, costs more than a
tick's sums): the tick at its time, made at once, and those after it on time, each at the one
before's end, under the same actuators.  It makes each happen at its time while the actuators
read the same, and asks again when they change or the batch is used up, saying how many it
made; the world goes back to where they left it (its snapshot before the batch's first tick,
or after it for a runtime that makes it at once, random streams too, and those ticks again:
the same sums), so what it answers is what tick() at
those times gives, to the bit (tests/test_world_ahead.py).  A runtime that comes a tick late
or more under the same actuators makes the batch's ticks due by then at once, each at its own
time (a tick runs from its own time: a late visit under the actuators it was computed for is
the same tick), and one that used a batch up under them asks for the next on time, from the
batch's end (within MAX_CATCHUP_US): a late runtime no longer throws a batch away.  The batch's
length follows how long the actuators hold: after a batch cut short at its k-th tick the next
is k ticks long (one when they change at every tick: nothing computed in vain; no snapshot for
a runtime that makes a batch's first tick at once),
and after two used whole it doubles, up to BATCH_US (a snapshot costs more than a tick); a
batch grown so and cut doubles the wait before the next growth (up to MOST_PATIENCE batches).

Pushes by hand (the control endpoint: virtual/worldctl.py) come from another thread: the world
checks them under a lock and applies them at its next tick (under :meth:`ahead`, its next
batch's first), in the simulation's time.
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Collection
from typing import Any

from ..world.robot import Part
from ..world.world import Actuation, Frame, World
from .world.units import split_degrees

#: worldfeed.py's number for each kind of part (a ranger by its driver: how it says "nothing
#: in reach")
FEED_KINDS = {"hcsr04": 0, "srf02": 1, "vl53l0x": 2, "sharp_gp2y0a02": 3, "imu": 4,
              "compass": 5, "gps": 6, "battery": 7, "motor": 8, "servo": 9, "stepper": 10,
              "encoder": 11}  # fmt: skip
Call = tuple[str, tuple[int, ...]]
#: an encoder edge: (board µs, pin A, pin B, +1 | -1)
Edge = tuple[int, int, int, int]
#: a tick computed ahead: (its board µs, the feed calls then, the edges of its run)
Tick = tuple[int, list[Call], list[Edge]]
#: ahead()'s last: the world's and the link's state before its first tick or after it (None:
#: one tick long, its first made at once), its actuation, its length, the ticks of it in that
#: state (0 or 1) and the time of the tick after them
Batch = tuple[tuple[Any, Any] | None, "Actuation", int, int, int]
MODES = ("coast", "drive", "brake", "shoot-through")
#: a reading's integers are below this in size: MicroPython's small integers on a 32-bit port
SMALL_INT = 1 << 30
#: the most of the board's time a late tick runs the world over at once (beyond any firmware
#: step or a loaded host's stall; beyond it, the host stopped the board and the world stands)
MAX_CATCHUP_US = 1_000_000
#: the most of the world's time :meth:`WorldLink.ahead` computes at once (its ticks on time)
BATCH_US = 100_000
#: batches used whole in a row before the next is twice as long (at first: see _adapt)
GROW_AFTER = 2
#: ... and the most it waits for (twice as many each time a batch it grew was cut short)
MOST_PATIENCE = 32

log = logging.getLogger(__name__)


def _kind(p: Part) -> int:
    return FEED_KINDS[p.driver if p.kind == "ranger" else p.kind]


class WorldLink:
    """``world`` for the board file's dict ``board``, its parts numbered for worldfeed.py; the
    ``absent`` ones (left unplugged: virtual/world/parts.py) are neither fed nor read."""

    def __init__(self, world: World, board: dict[str, Any], absent: Collection[str] = ()) -> None:
        self.world = world
        self.parts = [p for p in world.robot.parts.values() if p.name not in absent]
        self.index = {p.name: i for i, p in enumerate(self.parts)}
        self.order = {t["name"]: k for k, t in enumerate(board.get("transducers", []))}
        self.tick_us = max(1, round(world.spec.tick_ms * 1000))
        self.next_us = world.t_us
        self.pins = {p.name: (int(p.entry["pin_a"]), int(p.entry["pin_b"]))
                     for p in self.parts if p.kind == "encoder"}  # fmt: skip
        self.reads: list[Call] = []  #: asked of worldfeed.py before each tick, in this order
        for p in self.parts:
            i = self.index[p.name]
            if p.kind == "motor":
                self.reads.append(("motor", (i,)))
            elif p.kind == "servo":
                self.reads.append(("servo", (i,)))
            elif p.kind == "stepper":
                self.reads += [("stepper", (i,)), ("stepper_on", (i,))]
        self._lock = threading.Lock()
        self._off: set[str] = set()
        self._sent: dict[tuple[str, int], tuple[int, ...]] = {}  # (fn, part) -> what it was fed
        self.dropped = 0  #: readings not fed: not finite, or beyond a small integer
        self.skips = 0  #: the times the runtime came later than MAX_CATCHUP_US
        self.skipped_us = 0  #: ... and the board's time the world stood still for them
        self.most = max(1, BATCH_US // self.tick_us)  #: the longest batch, in ticks
        self.batch = self.most  #: ticks the next :meth:`ahead` computes (it adapts)
        self.batches = 0  #: :meth:`ahead`'s answers
        self.rewound = 0  #: ... and the times it went back over the last, cut short
        self._whole = 0  # (batches used whole in a row)
        self._patience = GROW_AFTER  # (... before the next grows)
        self._grown = False  # (the last batch was one grown)
        self._pushes: list[tuple[str, dict[str, Any]]] = []  # (checked, not yet in the world)
        self._batch: Batch | None = None
        #: the runtime makes each batch's first tick at once (Ahead, node's worldtick.mjs): the
        #: snapshot after it, none for a batch of one tick; else (AVR's rig may make none) before
        self.made_first = False
        self._replaying = False
        # the last actuators' values and their Actuation (the model only reads it; a function
        # of the values alone: nothing a snapshot or restore() changes)
        self._values: list[int] | None = None
        self._act = Actuation()
        # each kind of reading's plugged parts (name, number), in the frame's order (the board
        # file's: sensing.readers); every one is in its dict of a frame read
        self._sensing = {k: [(p.name, i) for i, p in enumerate(self.parts) if p.kind == k]
                         for k in ("ranger", "imu", "compass", "gps", "battery")}  # fmt: skip

    def attach(self) -> list[Call]:
        """worldfeed.attach's calls: each part's number, its transducer's in the board file,
        its kind and its pin (an ADC or PWM part's)."""
        return [("attach", (i, self.order[p.name], _kind(p), int(p.entry.get("pin", -1))))
                for i, p in enumerate(self.parts)]  # fmt: skip

    def due_us(self) -> int:
        return self.next_us

    def tick(self, now_us: int, values: list[int]) -> tuple[list[Call], list[Edge]]:
        """The world at ``now_us`` under the actuators' ``values`` (as :attr:`reads` asked):
        the feed calls to make now, and the edges to deliver at their times."""
        with self._lock:
            self._pushed()
            return self._tick(now_us, self._actuation(values))

    def ahead(self, now_us: int, used: int, values: list[int]) -> list[Tick]:
        """:attr:`batch` ticks at once: the one at ``now_us`` (the runtime makes it at once) and
        those after it on time (each at the one before's end), all under ``values`` (the
        runtime checks that they hold at each tick's time).  ``used``: how many of the last
        batch the runtime made happen (its first at least under :attr:`made_first`); fewer
        than all (the actuators changed), the world goes back to its state at the first it did
        not (restore, then the used ones again, the same sums), and the next batch is as long
        as that one was used."""
        with self._lock:
            if self._batch is not None:
                self._adapt(used)
            self._pushed()  # (before the snapshot: a going back keeps the batch's own pushes)
            act = self._actuation(values)
            if not self.made_first:
                self._batch = (self._snapshot(), act, self.batch, 0, now_us)
            first = (now_us, *self._tick(now_us, act))
            if self.made_first:
                snap = self._snapshot() if self.batch > 1 else None
                self._batch = (snap, act, self.batch, 1, self.next_us)
            self.batches += 1
            return [first, *self._run(self.next_us, act, self.batch - 1)]

    def _snapshot(self) -> tuple[Any, Any]:
        return self.world.snapshot(), self._state()

    def _adapt(self, used: int) -> None:
        """The last batch cut after ``used`` ticks: the world back there, the next as long;
        used whole: the next twice as long after :attr:`_patience` of them, a patience that
        doubles each time a batch grown so was cut (actuators that change at every tick)."""
        assert self._batch is not None
        n, least = self._batch[2], self._batch[3]
        if not least <= used <= n:
            raise ValueError(f"used {used} of a batch of {n} (at least {least}: made_first)")
        if used < n:
            self._back(used)
            self.rewound += 1
            if self._grown:
                self._patience = min(MOST_PATIENCE, 2 * self._patience)
            self.batch, self._whole, self._grown = max(1, used), 0, False
            return
        if self._grown:
            self._patience = GROW_AFTER
        self._whole, self._grown = self._whole + 1, False
        if self._whole >= self._patience and self.batch < self.most:
            self.batch, self._whole, self._grown = min(self.most, 2 * self.batch), 0, True

    def _run(self, now_us: int, act: Actuation, n: int) -> list[Tick]:
        """``n`` ticks under ``act``: the first at ``now_us``, each next at the one before's
        end."""
        ticks: list[Tick] = []
        while len(ticks) < n:
            ticks.append((now_us, *self._tick(now_us, act)))
            now_us = self.next_us
        return ticks

    def _back(self, used: int) -> None:
        """The world and what it fed as after the first ``used`` ticks of the last batch (the
        pushes since wait for the next batch)."""
        assert self._batch is not None
        snap, act, _n, done, at = self._batch
        assert snap is not None  # (a batch one tick long, its first made at once, is used whole)
        world, link = snap
        self.world.restore(world)
        sent, off, self.dropped, self.skips, self.skipped_us, self.next_us = link
        self._sent, self._off = dict(sent), set(off)
        self._replaying = True  # (a pause it stood still for was said the first time)
        try:
            self._run(at, act, used - done)
        finally:
            self._replaying = False

    def _state(self) -> tuple[dict[tuple[str, int], tuple[int, ...]], set[str], int, int, int, int]:
        return (dict(self._sent), set(self._off), self.dropped, self.skips, self.skipped_us,
                self.next_us)  # fmt: skip

    def _pushed(self) -> None:
        """The pushes by hand since the last tick into the world (at its time now)."""
        for kind, args in self._pushes:
            self.world.command(kind, args)
        self._pushes = []

    def _tick(self, now_us: int, act: Actuation) -> tuple[list[Call], list[Edge]]:
        edges: list[Edge] = []
        self._skip(now_us - MAX_CATCHUP_US - self.world.t_us)
        if now_us > self.world.t_us + self.tick_us:  # (late: the stretch up to now first)
            edges += self._edges(self.world.step(now_us, act, read=False))
        frame = self.world.step(now_us + self.tick_us, act)  # (a little late: from its time)
        self.next_us = now_us + self.tick_us
        sent, calls = self._sent, []
        for fn, args in self._calls(frame):
            if sent.get((fn, args[0])) != args:  # (what changed only: a call costs)
                sent[fn, args[0]] = args
                calls.append((fn, args))
        return calls, edges + self._edges(frame)

    def _skip(self, us: int) -> None:
        """The world stands still for ``us`` (> 0: the runtime came that much later than
        MAX_CATCHUP_US after the world's time)."""
        if us <= 0:
            return
        self.world.skip(us)
        self.skips += 1
        self.skipped_us += us
        if not self._replaying:
            log.warning("world: the board's clock jumped %.3f s ahead of the world (its host "
                        "paused?): the world ran the last %.3f s and stood still for the "
                        "rest", (us + MAX_CATCHUP_US) / 1e6, MAX_CATCHUP_US / 1e6)  # fmt: skip

    def push(self, kind: str, args: dict[str, Any]) -> None:
        """A push by hand, checked now (WorldFileError: one line), applied at the next tick (of
        :meth:`ahead`: at the next batch's first)."""
        with self._lock:
            self._pushes.append((kind, self.world.checked(kind, args)))

    def state(self) -> dict[str, Any]:
        with self._lock:
            return {**self.world.state(), "readings_dropped": self.dropped,
                    "skips": self.skips, "skipped_s": self.skipped_us / 1e6,
                    "batches": self.batches, "rewound": self.rewound}  # fmt: skip

    # ---- integers to and from the simulator ----
    def _actuation(self, values: list[int]) -> Actuation:
        if values == self._values:  # (mostly: the actuators hold)
            return self._act
        act = Actuation()
        got = dict(zip([(fn, a[0]) for fn, a in self.reads], values, strict=True))
        for p in self.parts:
            i = self.index[p.name]
            if p.kind == "motor":
                code = got[("motor", i)]
                mode, rest = divmod(code, 100000)
                act.motors[p.name] = ((rest - 50000) / 10000, MODES[min(mode, 3)])
            elif p.kind == "servo":
                pulse = got[("servo", i)]
                act.servos[p.name] = None if pulse < 0 else float(pulse)
            elif p.kind == "stepper":
                act.steppers[p.name] = (got[("stepper", i)], bool(got[("stepper_on", i)]))
        self._values, self._act = list(values), act
        return act

    def _edges(self, frame: Frame) -> list[Edge]:
        out: list[Edge] = []
        for name, edges in frame.edges.items():
            if edges and name in self.pins:  # (at rest: none)
                a, b = self.pins[name]
                out += [(t, a, b, d) for t, d in edges]
        out.sort()
        return out

    def _calls(self, frame: Frame) -> list[Call]:
        calls: list[Call] = []
        if frame.failed or self._off:  # (mostly neither)
            silent = set(frame.failed) & set(self.index)
            for name in silent ^ self._off:  # (failed or back: said once)
                calls.append(("off", (self.index[name], 1 if name in silent else 0)))
            self._off = silent
        of = self._sensing
        for name, i in of["ranger"]:
            metres = frame.ranges[name]
            self._add(calls, "ranger", i, [-1.0 if metres is None else metres * 1000])
        for name, i in of["imu"]:
            imu, deg = frame.imus[name], math.degrees
            (ax, ay, az), (gx, gy, gz) = imu.accel, imu.gyro
            self._add(calls, "imu", i, [ax / 9.80665 * 16384, ay / 9.80665 * 16384,
                                        az / 9.80665 * 16384, deg(gx) * 131, deg(gy) * 131,
                                        deg(gz) * 131])  # fmt: skip
        for name, i in of["compass"]:
            x, y, z = frame.fields[name]
            self._add(calls, "field", i, [x * 12000, y * 12000, z * 12000])
        for name, i in of["gps"]:
            self._add(calls, "fix", i, _fix(frame.fixes[name]))
        for name, i in of["battery"]:
            self._add(calls, "volts", i, [frame.volts[name] * 1000])
        return calls

    def _add(self, calls: list[Call], fn: str, i: int, values: list[float]) -> None:
        """Part ``i``'s reading as feed call ``fn``, rounded, unless it is not a number a part
        holds (it keeps its last reading: counted)."""
        args = _small_ints(values)
        if args is None:
            self.dropped += 1
        else:
            calls.append((fn, (i, *args)))


def _fix(fix: Any) -> list[float]:
    """A fix as worldfeed.fix's numbers (its whole degrees and 1e-7 degree split here)."""
    if not (math.isfinite(fix.latitude_deg) and math.isfinite(fix.longitude_deg)):
        return [math.nan]
    lat, lon = split_degrees(fix.latitude_deg), split_degrees(fix.longitude_deg)
    knots = fix.speed_m_s * 3600 / 1852
    course = round(fix.course_deg * 10) % 3600 if math.isfinite(fix.course_deg) else math.nan
    return [*lat, *lon, fix.altitude_m * 10, knots * 10, course, fix.satellites, fix.hdop * 10]


def _small_ints(values: list[float]) -> tuple[int, ...] | None:
    """``values`` rounded, or None when one is not finite or not a small integer of a 32-bit
    MicroPython (|v| < 2^30: a larger one would be an object in the board's heap)."""
    if not all(map(math.isfinite, values)):
        return None
    out = tuple(map(round, values))
    return out if min(out) >= -SMALL_INT and max(out) < SMALL_INT else None


def next_from(now_us: int, end_us: int, held: bool) -> int:
    """Where a runtime's next batch starts: at the last one's end ``end_us`` when it was used
    up under the actuators it was computed for (``held``: its ticks stay on time), unless that
    is more than MAX_CATCHUP_US ago; else at ``now_us`` (the actuators' change seen now)."""
    return end_us if held and now_us - end_us <= MAX_CATCHUP_US else now_us


class Ahead:
    """A runtime's side of :meth:`WorldLink.ahead` (CPython's; node's is worldtick.mjs): the
    batch's ticks made one by one at their times while the actuators hold."""

    def __init__(self, link: WorldLink) -> None:
        self.link = link
        link.made_first = True  # (tick() makes a batch's first at once)
        self.batch: list[Tick] = []
        self.used = 0
        self.values: list[int] | None = None
        self.end = link.due_us()

    def due_us(self) -> int:
        return self.batch[self.used][0] if self.used < len(self.batch) else self.end

    def tick(self, now_us: int, values: list[int]) -> Tick:
        """The tick to make next, at due_us() (``now_us`` or before), the actuators reading
        ``values`` now: the batch's next while they read as the batch took them (late too: it
        runs from its own time); else the first of a new batch: from the last one's end when
        that was used up under them (within MAX_CATCHUP_US), from ``now_us`` when they changed
        (as a tick one at a time: their change is seen now)."""
        held = values == self.values
        if held and self.used < len(self.batch):
            self.used += 1
            return self.batch[self.used - 1]
        now_us = next_from(now_us, self.end, held)
        self.batch = self.link.ahead(now_us, self.used, values)
        self.values, self.used, self.end = values, 1, self.link.due_us()
        return self.batch[0]
