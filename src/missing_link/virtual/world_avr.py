"""The world beside a board file's AVR firmware in simavr (virtual/avrboard.py): the world link
(worldlink.py) runs in the missing-link board process and drives the rig's parts through the
rig's control lines (firmware/avr/sim/*.h), as the rig's own models do without a world.

Theory of operation
-------------------
At start every wheel of the rig is taken from the rig's own motor model (``wheel K off``,
motor.h): from then on only the world turns its encoder.  Then the world and the rig trade one
line each way a batch of ticks (the rig's world.c: ``tick ASKS|T0 FEEDS|T1 FEEDS|...|TN``): the
world computes up to the next 100 ms of ticks at once (worldlink.py's ahead) on the assumption that
the drives hold, and each tick's FEEDS are the lines that put what it says into the parts (a
ranger's target, ``hcsr04 MM``, ``srf02 CM``, ``sharp MM``; the IMU's specific force and turn
rate in SI, ``imu K ...``; the battery's voltage at its ADC pin through its divider, ``ain CH
MV``; a part that fails silent taken off the bus, ``imu_absent``, ``srf02_absent``; each
encoder's edges of the tick as one ``enc K STEPS``, which the rig makes 100 µs apart from then:
they come at the tick, not at their own times).  The rig makes each tick at its simulated time T
(simavr's µs, never the host's clock) while the drives (``motor``: duty and direction, as the
rig's model reads them from Timer0's outputs; the stepper's) read as the rig last answered
them (a line that came late: the ticks due by then at once, each its own), and answers at the
first tick where they do not, or at the batch's end, with that time, how many ticks it made,
the drives then and the feeds' errors (counted, the first said once).  The answer comes to
:meth:`AvrWorld.answer` in the thread that reads the rig (AvrBoard.on_tick): the world goes back
to the first tick not made and computes the next batch under the drives, from the batch's end
when it was made whole under them (the ticks stay on time), else from the answer's time (their
change seen then, as one tick at a time would), and sends it (ahead: the same sums as ticking
one at a time at those times, to the bit: tests/test_world_avr_ahead.py).  So nothing
sleeps to a tick or asks for the time: the rig wakes the world once a batch (each wake-up of
the world costs more than a tick's sums), in the simulation's time (simavr runs paced to the
host's clock; an answer that comes late first runs the world up to the simulation's time:
worldlink.py).  A batch's line is cut to the ticks that fit the rig's longest line
(RIG_LINE_MAX; the rest asked again at the cut).  The rig ending ends the ticks (no answer
comes).

What the rig has no control line for is not fed: the GPS's position (its fix stays where the
rig's model puts it), a compass (the rig has none), a VL53L0X.
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Callable, Collection
from typing import Any

from .worldlink import Call, Edge, WorldLink, next_from

G = 9.80665
#: the longest line the rig takes (rig_sim's world.h), a batch's line cut to it
RIG_LINE_MAX = 16383
#: the world link's integers back to SI (worldlink.py: the MPU-6050's LSB at +-2 g, +-250 deg/s)
ACCEL_LSB, GYRO_LSB = 16384 / G, 131.0


def sim_us(ctl: Callable[[str], str]) -> int:
    """The simulation's time, simavr's µs since the rig started (its ``stats`` line)."""
    return _stats_us(ctl("stats"))


def _stats_us(stats: str) -> int:
    words = stats.split()
    return int(words[words.index("sim_us") + 1])


log = logging.getLogger(__name__)


class AvrWorld:
    """``link``'s world on the rig answering ``ctl`` (AvrBoard.ctl_lines: lines in, as many
    out, one round trip), for the board file's ``transducers`` (the rig numbers each kind's
    parts in their order, the ``absent`` ones left out: deploy/avrsim.rig_parts); ``post``
    (AvrBoard.ctl_post) sends a tick's line, whose answer the board hands to :meth:`answer`."""

    def __init__(
        self,
        link: WorldLink,
        ctl: Callable[[list[str]], list[str]],
        transducers: list[dict[str, Any]],
        absent: Collection[str] = (),
        post: Callable[[str], None] | None = None,
    ) -> None:
        self.link = link
        link.made_first = True  # (the rig makes a batch's first tick as its line comes: world.c)
        self.ctl = ctl
        self.post = post or (lambda line: None)
        here = [t for t in transducers if t["name"] not in absent]
        self.entry = {t["name"]: t for t in here}
        self.k: dict[str, int] = {}  # a part's number among the rig's parts of its kind
        for kind in ("quadrature", "hbridge", "mpu6050"):
            for k, t in enumerate(x for x in here if x["driver"] == kind):
                self.k[t["name"]] = k
        self.wheels = min(sum(t["driver"] == d for t in here) for d in ("quadrature", "hbridge"))
        self.enc_of_pin = {a: self.k[name] for name, (a, _b) in link.pins.items()}
        #: what the rig says with each tick's time: the drives, the stepper's
        stepper = any(fn == "stepper" for fn, _a in link.reads)
        self.asks = "motor;stepper" if stepper else "motor"
        self.ticks = 0  #: the ticks the rig made
        self.failed: str | None = None
        self.rig_errors = 0  #: the rig's errors to the world's lines (the first one logged)
        self._stop = threading.Event()
        self._values: list[int] = []  # the pending batch's drives
        self._sent: list[tuple[int, list[str]]] = []  # ... its ticks: their times and lines
        self._end = 0  # ... and where it asks the world again
        #: when a list: each tick the rig made, (µs, the drives' values, its lines)
        self.record: list[tuple[int, list[int], list[str]]] | None = None

    # ---- the hand and the state (virtual/worldctl.py) ----
    def push(self, kind: str, args: dict[str, Any]) -> None:
        self.link.push(kind, args)

    def state(self) -> dict[str, Any]:
        state = self.link.state()
        if self.rig_errors:
            state["rig_errors"] = self.rig_errors
        if self.failed is not None:  # (the world stopped: the board runs on its last readings)
            state["stopped"] = self.failed
        return state

    def start(self) -> None:
        self.ctl([f"wheel {k} off" for k in range(self.wheels)])
        self.post(f"tick {self.asks}|{self.link.due_us()}")  # (no tick yet: asked at the first's)

    def stop(self) -> None:
        self._stop.set()

    def answer(self, line: str) -> None:
        """The rig's ``tick SIM_US MADE ASKS|ERRORS FIRST`` at a tick's time: the ticks it made
        counted, the next batch's line sent; never raises (it runs in the thread that reads
        the rig)."""
        if self._stop.is_set() or self.failed is not None:
            return
        try:
            if line.startswith("error "):  # (the rig refused the tick line itself)
                self.rig_errors += 1
                raise ValueError(f"the rig refused the world's tick: {line[:200]!r}")
            head, fed = line.split("|", 1)
            _tick, now, made_s, asked = head.split(" ", 3)
            made = int(made_s)
            if not 0 <= made <= len(self._sent):
                raise ValueError(f"the rig made {made} of {len(self._sent)} ticks")
            values, n = self.drives(asked), int(fed.partition(" ")[0])  # (all read first)
            self._said(n, fed)
            self._made(made)
            self.post(self._next(int(now), made, values))
        except Exception as e:  # noqa: BLE001 - (a rig that ended, a line it mangled): said once
            self.failed = f"{type(e).__name__}: {e}"
            if not self._stop.is_set():
                log.error("world: stopped after %d ticks (the board runs on its last readings): "
                          "%s", self.ticks, self.failed)  # fmt: skip

    def _said(self, n: int, fed: str) -> None:
        """The rig's count ``n`` of the errors among its answers to the feeds, and the first
        (``fed``: "N FIRST"): counted, the first ever logged."""
        if n and not self.rig_errors:
            log.warning("world: the rig refused a line: %s", fed.partition(" ")[2][:200])
        self.rig_errors += n

    def _made(self, made: int) -> None:
        self.ticks += made
        if self.record is not None:
            self.record += [(t, self._values, lines) for t, lines in self._sent[:made]]

    def _next(self, now: int, made: int, values: list[int]) -> str:
        """The next batch's line: the world back to the first tick not made, ticked ahead under
        ``values`` from the last line's end when the rig made it whole under them (Ahead's rule:
        its ticks stay on time), else from ``now``; as many ticks as fit the rig's line."""
        held = values == self._values and made == len(self._sent)
        ticks = self.link.ahead(next_from(now, self._end, held), made, values)
        self._values, self._sent = values, []
        entries: list[str] = []
        size = len(self.asks) + 48  # ("tick ", the bars, the end's time)
        for t, calls, edges in ticks:
            lines = self.lines(calls, edges)
            entry = f"{t} {';'.join(lines)}" if lines else str(t)
            size += len(entry) + 1
            if size > RIG_LINE_MAX and entries:  # (the rest asked again from the cut)
                break
            entries.append(entry)
            self._sent.append((t, lines))
        self._end = ticks[len(entries)][0] if len(entries) < len(ticks) else self.link.due_us()
        return f"tick {self.asks}|{'|'.join(entries)}|{self._end}"

    def tick(self, now: int, values: list[int]) -> list[str]:
        """The world's tick at ``now`` under the actuators' ``values`` one at a time (what the
        batches give, to the bit): the lines that put what it says into the rig's parts."""
        return self.lines(*self.link.tick(now, values))

    def lines(self, calls: list[Call], edges: list[Edge]) -> list[str]:
        """A tick's feed calls and edges as the rig's control lines."""
        lines = [line for fn, args in calls for line in self._lines(fn, args)]
        steps: dict[int, int] = {}
        for _t, a, _b, d in edges:
            k = self.enc_of_pin[a]
            steps[k] = steps.get(k, 0) + d
        lines += [f"enc {k} {n}" for k, n in sorted(steps.items()) if n]
        return lines

    def drives(self, asked: str) -> list[int]:
        """The integers worldlink.py's reads ask for, from the rig's answers to the asks (its
        ``motor`` and ``stepper`` lines, ';' between)."""
        motor, stepper = (asked + ";stepper 0 0").split(";")[:2]
        drives = motor.split()[1:]  # (D0 R0 D1 R1 ...: each motor's drive)
        steps = stepper.split()[1:]
        out = []
        for fn, (i,) in self.link.reads:
            name = self.link.parts[i].name
            if fn == "motor":
                k = self.k[name]
                duty = float(drives[2 * k]) * (-1 if drives[2 * k + 1] == "1" else 1)
                out.append(100000 + 50000 + round(duty * 10000))  # (driven: worldlink.MODES)
            elif fn == "servo":
                out.append(-1)  # (the rig measures its pulse, it does not hand it on: none)
            elif fn == "stepper":
                out.append(int(steps[0]))
            else:  # stepper_on
                out.append(int(steps[1]))
        return out

    def _lines(self, fn: str, args: tuple[int, ...]) -> list[str]:
        """worldfeed.py's call as the rig's control lines (none: the rig has none for it)."""
        part = self.link.parts[args[0]]
        drv = self.entry[part.name]["driver"]
        if fn == "ranger":
            mm = args[1]
            if drv == "hcsr04":
                return [f"hcsr04 {max(mm, 0)}"]
            if drv == "srf02":
                return [f"srf02 {max(round(mm / 10), 0)}", f"echo {int(mm >= 0)}"]
            if drv == "sharp_gp2y0a02":
                return [f"sharp {mm if mm >= 0 else 3000}"]
        elif fn == "imu" and drv == "mpu6050":
            a = [v / ACCEL_LSB for v in args[1:4]]
            g = [math.radians(v / GYRO_LSB) for v in args[4:7]]
            return [f"imu {self.k[part.name]} " + " ".join(f"{v:.5f}" for v in (*a, *g)) + " 25"]
        elif fn == "volts" and drv == "battery":
            e = self.entry[part.name]
            top, bottom = float(e.get("r_top", 10000.0)), float(e.get("r_bottom", 3300.0))
            return [f"ain {int(e['pin'])} {round(args[1] * bottom / (top + bottom))}"]
        elif fn == "off" and drv == "mpu6050":
            return [f"imu_absent {self.k[part.name]} {args[1]}"]
        elif fn == "off" and drv == "srf02":
            return [f"srf02_absent {args[1]}"]
        return []
