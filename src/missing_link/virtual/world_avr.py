"""The world beside a board file's AVR firmware in simavr (virtual/avrboard.py): the world link
(worldlink.py) runs in the missing-link board process and drives the rig's parts through the
rig's control lines (firmware/avr/sim/*.h), as the rig's own models do without a world.

Theory of operation
-------------------
At start every wheel of the rig is taken from the rig's own motor model (``wheel K off``,
motor.h): from then on only the world turns its encoder.  A thread of its own (``world``) reads
the simulation's time (``stats``: simavr's µs, never the host's clock) and, when it has reached
the world's next tick, reads the motors' drives (``motor``: duty and direction, as the rig's
model reads them from Timer0's outputs) and the stepper, ticks the world link with them, and
puts what the world says into the parts: a ranger's target (``hcsr04 MM``, ``srf02 CM``,
``sharp MM``), the IMU's specific force and turn rate in SI (``imu K ...``), the battery's
voltage at its ADC pin through its divider (``ain CH MV``), a part that fails silent taken off
the bus (``imu_absent``, ``srf02_absent``), and each encoder's edges of the tick as one
``enc K STEPS`` (the rig makes them 100 µs apart from then: they come at the tick, not at their
own times).  Then it sleeps until the next tick's simulated time (simavr runs paced to the
host's clock, so a simulated ms takes about a real one); a tick that comes late first runs the
world up to the simulation's time (worldlink.py).  The rig ending ends the thread.

What the rig has no control line for is not fed: the GPS's position (its fix stays where the
rig's model puts it), a compass (the rig has none), a VL53L0X.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Collection
from typing import Any

from .worldlink import WorldLink

G = 9.80665
#: the world link's integers back to SI (worldlink.py: the MPU-6050's LSB at +-2 g, +-250 deg/s)
ACCEL_LSB, GYRO_LSB = 16384 / G, 131.0


def sim_us(ctl: Callable[[str], str]) -> int:
    """The simulation's time, simavr's µs since the rig started (its ``stats`` line)."""
    words = ctl("stats").split()
    return int(words[words.index("sim_us") + 1])


class AvrWorld:
    """``link``'s world on the rig answering ``ctl`` (AvrBoard.ctl: one line in, one out), for
    the board file's ``transducers`` (the rig numbers each kind's parts in their order, the
    ``absent`` ones left out: deploy/avrsim.rig_parts)."""

    def __init__(
        self,
        link: WorldLink,
        ctl: Callable[[str], str],
        transducers: list[dict[str, Any]],
        absent: Collection[str] = (),
    ) -> None:
        self.link = link
        self.ctl = ctl
        here = [t for t in transducers if t["name"] not in absent]
        self.entry = {t["name"]: t for t in here}
        self.k: dict[str, int] = {}  # a part's number among the rig's parts of its kind
        for kind in ("quadrature", "hbridge", "mpu6050"):
            for k, t in enumerate(x for x in here if x["driver"] == kind):
                self.k[t["name"]] = k
        self.wheels = min(sum(t["driver"] == d for t in here) for d in ("quadrature", "hbridge"))
        self.enc_of_pin = {a: self.k[name] for name, (a, _b) in link.pins.items()}
        self.ticks = 0
        self.failed: str | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="world", daemon=True)

    # ---- the hand and the state (virtual/worldctl.py) ----
    def push(self, kind: str, args: dict[str, Any]) -> None:
        self.link.push(kind, args)

    def state(self) -> dict[str, Any]:
        return self.link.state()

    def start(self) -> None:
        for k in range(self.wheels):
            self.ctl(f"wheel {k} off")
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                now = sim_us(self.ctl)
                due = self.link.due_us()
                if now < due:
                    time.sleep(min(0.01, (due - now) / 1e6))
                    continue
                self.tick(now)
        except Exception as e:  # noqa: BLE001 - the rig ended (power off, a crash): said once
            self.failed = f"{type(e).__name__}: {e}"

    def tick(self, now: int) -> None:
        calls, edges = self.link.tick(now, self._reads())
        for fn, args in calls:
            for line in self._lines(fn, args):
                self.ctl(line)
        steps: dict[int, int] = {}
        for _t, a, _b, d in edges:
            k = self.enc_of_pin[a]
            steps[k] = steps.get(k, 0) + d
        for k, n in sorted(steps.items()):
            if n:
                self.ctl(f"enc {k} {n}")
        self.ticks += 1

    def _reads(self) -> list[int]:
        """The integers worldlink.py's reads ask for, from the rig's lines."""
        drives = self.ctl("motor").split()[1:]  # (D0 R0 D1 R1 ...: each motor's drive)
        stepper = self.ctl("stepper").split()[1:] if any(
            fn == "stepper" for fn, _a in self.link.reads) else ["0", "0"]  # fmt: skip
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
                out.append(int(stepper[0]))
            else:  # stepper_on
                out.append(int(stepper[1]))
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
