"""The clock-sync simulation's clocks and links (syncsim.py runs them): a board clock as a
function of host time (offset, skew, resolution, resets), and the link models that turn a send
time into an arrival time or a loss (``pty``, ``usb``, ``ftdi``: syncsim.py says what each
models).  Pure and seeded."""

from __future__ import annotations

import math
import random

import numpy as np

NS = 1_000
MS = 1_000_000
S = 1_000_000_000


# ---- board clocks ------------------------------------------------------------------------------
class BoardClock:
    """Free-running µs counter: offset + (1 + skew + wander(t)) * t, floored to whole ticks.

    Wander: a random walk of the rate (``walk`` per sqrt(s)) plus a slow sinusoid (temperature).
    """

    def __init__(
        self,
        rng: random.Random,
        duration_s: float,
        *,
        skew: float = 100e-6,
        walk: float = 0.01e-6,
        sine: float = 1e-6,
        sine_period_s: float = 600.0,
    ) -> None:
        self.offset_us = rng.uniform(1e6, 1e9)
        dt = 0.1
        n = int(duration_s / dt) + 3
        steps = np.array([rng.gauss(0.0, walk * math.sqrt(dt)) for _ in range(n)])
        phase = rng.uniform(0, 2 * math.pi)
        t = np.arange(n) * dt
        rate = skew + np.cumsum(steps) + sine * np.sin(2 * math.pi * t / sine_period_s + phase)
        self._t = t
        self._int = np.concatenate(([0.0], np.cumsum((rate[1:] + rate[:-1]) / 2 * dt)))  # s
        self.skew = skew

    def us(self, t_ns: float) -> int:
        ts = t_ns / S
        extra = float(np.interp(ts, self._t, self._int))
        return math.floor(self.offset_us + (ts + extra) * 1e6)


# ---- links -------------------------------------------------------------------------------------
class Link:
    name = "link"
    byte_ns = 0.0  # time on the wire per byte after t3 (0: not a byte-serial link)

    def __init__(self, rng: random.Random, duration_s: float) -> None:
        self.rng = rng
        self.bursts: list[tuple[float, float]] = []
        t = rng.expovariate(1 / 20.0)
        while t < duration_s:
            d = rng.uniform(0.2, 1.0)
            self.bursts.append((t * S, (t + d) * S))
            t += d + rng.expovariate(1 / 20.0)

    def _burst(self, t: float) -> float:
        for a, b in self.bursts:
            if a <= t < b:
                return self.rng.expovariate(1 / 200.0) * NS
            if a > t:
                break
        return 0.0

    def _tail(self, p: float = 0.03, scale_us: float = 15.0) -> float:
        if self.rng.random() < p:
            return min(self.rng.paretovariate(1.5) * scale_us, 3000.0) * NS
        return 0.0

    def lost(self) -> bool:
        return self.rng.random() < 0.005

    def up(self, t: float) -> float:
        """Arrival of the request's last byte at the board."""
        raise NotImplementedError

    def down(self, t: float, nbytes: int) -> float:
        """Host time the reply (first byte leaving at t) has been read."""
        raise NotImplementedError

    def board_stamp_lag(self) -> float:
        """From the request's arrival to the board's t2 stamp."""
        return self.rng.expovariate(1 / 1.0) * NS

    def board_turnaround(self) -> float:
        """From the t2 stamp to the t3 stamp."""
        return (10.0 + self.rng.expovariate(1 / 5.0)) * NS


class PtyLink(Link):
    name = "pty"

    def up(self, t: float) -> float:
        r = self.rng
        return t + (8.0 + r.expovariate(1 / 3.0)) * NS + self._tail() + self._burst(t)

    def down(self, t: float, nbytes: int) -> float:
        r = self.rng
        return t + (9.0 + r.expovariate(1 / 3.0)) * NS + self._tail() + self._burst(t)


class UsbFullSpeedLink(Link):
    name = "usb"
    frame_ns: float = 1 * MS

    def __init__(self, rng: random.Random, duration_s: float) -> None:
        super().__init__(rng, duration_s)
        self.phase = rng.uniform(0, self.frame_ns)
        # The frame clock is the host controller's crystal, not the CPU's: ±50 ppm apart.
        self.frame_ns = MS * (1 + rng.uniform(-50e-6, 50e-6))

    def up(self, t: float) -> float:
        r = self.rng
        return t + (25.0 + r.expovariate(1 / 20.0)) * NS + self._tail() + self._burst(t)

    def _frame_end(self, t: float) -> float:
        f = self.frame_ns
        return math.floor((t - self.phase) / f + 1) * f + self.phase

    def down(self, t: float, nbytes: int) -> float:
        r = self.rng
        moved = t + (5.0 + nbytes * 0.7) * NS  # the IN packet, 12 Mbit/s
        done = self._frame_end(moved)
        return done + (10.0 + r.expovariate(1 / 10.0)) * NS + self._tail() + self._burst(t)


class FtdiUartLink(UsbFullSpeedLink):
    name = "ftdi"
    baud = 921_600
    request_bytes = 5

    def __init__(self, rng: random.Random, duration_s: float) -> None:
        super().__init__(rng, duration_s)
        self.byte_ns = 10 * S / self.baud
        self.timer_phase = rng.uniform(0, MS)
        self.timer_ns = MS * (1 + rng.uniform(-50e-6, 50e-6))  # the bridge's own crystal

    def up(self, t: float) -> float:
        at_bridge = super().up(t)
        return at_bridge + self.request_bytes * self.byte_ns

    def down(self, t: float, nbytes: int) -> float:
        r = self.rng
        last = t + nbytes * self.byte_ns
        tick = (
            math.ceil((last - self.timer_phase) / self.timer_ns) * self.timer_ns + self.timer_phase
        )
        # The bridge's pending bulk IN is serviced within the frame (an xHCI host reports the
        # completion at once), then host interrupt latency.
        usb = tick + (20.0 + r.expovariate(1 / 20.0)) * NS
        return usb + (10.0 + r.expovariate(1 / 10.0)) * NS + self._tail() + self._burst(t)


LINKS: dict[str, type[Link]] = {"pty": PtyLink, "usb": UsbFullSpeedLink, "ftdi": FtdiUartLink}
