# The board clock: a free-running microsecond counter, 64 bit, never adjusted (spec 2.1).
#
# MicroPython's time.ticks_us() wraps (period TICKS_MAX + 1, 2**30 on most ports, ~17.9 min), so
# WrappingClock extends it: every read adds the modular difference to the previous read.  The
# only rule is that the clock is read at least once per half period; the runtime's process loop
# reads it many times a second.  CPython has time.monotonic_ns(), which does not wrap.

import time


class WrappingClock:
    # Extend a wrapping tick counter to 64 bit.  ticks(): raw counter in [0, period).
    def __init__(self, ticks, period):
        if period & (period - 1):
            raise ValueError("tick period must be a power of two")
        self._ticks = ticks
        self._mask = period - 1
        self._half = period >> 1
        self._last = ticks()
        self._total = 0

    def __call__(self):
        raw = self._ticks()
        d = (raw - self._last) & self._mask
        if d >= self._half:
            # A read that looks like a jump of more than half a period is a slightly older value
            # (e.g. read from an interrupt): treat it as "no time passed" rather than a wrap.
            return self._total
        self._last = raw
        self._total += d
        return self._total


def _monotonic_us():
    return time.monotonic_ns() // 1000


def default_clock():
    # The clock that stamps samples and answers a2jClock on this interpreter.
    if hasattr(time, "ticks_us"):
        period = time.ticks_add(0, -1) + 1
        return WrappingClock(time.ticks_us, period)
    return _monotonic_us


def _gcd(a, b):
    while b:
        a, b = b, a % b
    return a


def resolution_us(clock, steps=5, limit_us=100000):
    # The clock's tick, measured: the gcd of a few observed steps (reads cost several µs on a
    # microcontroller, so one step alone overstates it).  1 on RP2040/ESP32 timers; ports whose
    # ticks_us counts in milliseconds (the WebAssembly port) say 1000, and the host's bound
    # widens by it (property clock.res_us).
    start = last = clock()
    res = 0
    seen = 0
    while seen < steps:
        now = clock()
        if now != last:
            res = _gcd(res, now - last)
            last = now
            seen += 1
        elif now - start > limit_us:
            break
    return max(1, res)


def new_epoch():
    # A value that differs at every boot, so the host can tell a reset (property clock.epoch).
    try:
        import os

        raw = os.urandom(4)
    except Exception:  # noqa: BLE001 - ports without urandom fall back to the tick counter
        t = time.ticks_us() if hasattr(time, "ticks_us") else time.monotonic_ns()
        raw = bytes(((t >> s) & 0xFF for s in (0, 8, 16, 24)))
    return "".join("%02x" % b for b in raw)
