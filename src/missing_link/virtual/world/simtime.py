"""Simulated time for the simulator's fast mode (host.mjs --fast): a `time` module whose clock is
the simulation's, so ten simulated minutes need not take ten real ones.  host.mjs puts it in
sys.modules as `time` before anything imports `time`, so the firmware (board/clock.py), the
simulated machine and the devices all read it.  The MicroPython subset only.

Theory of operation
-------------------
The clock counts simulated µs, wrapping at TICKS_MAX + 1 (2^30) as the RP2040 port's ticks_us does
(board/clock.py extends it to 64 bit, as on a board; ticks_add refuses a delta of 2^29 or more
either way, OverflowError, as the port's does), with the ns below a µs kept apart (work
is charged in ns: a clock read costs 9.6 µs, so reads land 9 or 10 µs apart, as on a board).
Between two firmware steps the host sets it (set_now, fastclock.mjs).  Within a step it moves
only by what the step's work costs in the cost model (simcost.py), charged as the work happens,
so every read sees the work before it: the step's own cost (mpyhost.py), each clock read
(READ_NS), the link's bytes, each peripheral call (machine.py), each heap scan and the blocks
allocated before it (simgc.py); and by what a sleep slept (sleep_us, a pulse waited for:
machine.time_pulse_us) and what a collection is charged at gc.collect() (simgc.py).  The step's
total (slept(), with the ns left over: ns()) goes back to the host with its output.  Never by
the host's CPU time or its clock: the same simulation moves the clock the same way on any
machine.  The simulator's own reads (the world's devices, the host's bookkeeping, a test's
control request) are free: now_us(), or while `free` is set.  ticks_ms and time() count the
same time unwrapped (in ms wrapping at 2^30 ms, 12.4 days, as the port's ticks_ms; and whole s),
kept beside the µs as small integers: they do not restart when ticks_us wraps (17.9 minutes).
"""

from . import simcost

# (written as small integers: the period, 2^30, is a long integer on a 32-bit port, and any
# sum with it would put one in the board's heap on every call, where a board's own clock
# allocates nothing)
TICKS_MAX = 0x3FFFFFFF  # the period less one
TICKS_HALF = 0x20000000
_WORD_MAX = 0x7FFFFFFF  # (only compared with where ticks_add refuses: no long integer a call)

_now = 0  # simulated µs, wrapped
_ns = 0  # ... and the ns below it (0..999)
_slept = 0  # µs the clock moved in the current step
_ms = 0  # ... the same time in ms (unwrapped: wraps at 2^30 ms as the port's ticks_ms)
_sub = 0  # ... the µs below that ms (0..999)
_s = 0  # ... and in whole seconds (time())
_ms_in_s = 0  # ... the ms below that second (0..999)
free = False  # the simulator reads the clock: no charge (mpyhost.py)


def set_now(us, ns=0):
    # a new step begins at simulated µs `us` (wrapped) and `ns` below it: nothing spent yet
    global _now, _ns, _slept
    us &= TICKS_MAX
    _count(ticks_diff(us, _now))  # (a step's moves are small: an idle jump, an edge's time)
    _now = us
    _ns = ns
    _slept = 0


def advance(us):
    # the clock moves on by `us` (a sleep, a transfer on a bus, a charge)
    global _now, _slept
    if us > 0:
        _now = _wrap_add(_now, us)  # (a sleep of any length: ticks_add takes under 2^29)
        _slept += us
        _count(us)


def _count(us):
    # the unwrapped ms and s move on by `us` (either way), in small integers only
    global _ms, _sub, _s, _ms_in_s
    sub = _sub + us % 1000
    ms = us // 1000 + sub // 1000
    _sub = sub % 1000
    _ms = _wrap_add(_ms, ms)
    within = _ms_in_s + ms
    _s += within // 1000
    _ms_in_s = within % 1000


def charge_ns(ns):
    # the work of `ns` nanoseconds on the board: the clock moves on by it
    global _ns
    if ns > 0:
        total = _ns + ns
        _ns = total % 1000
        advance(total // 1000)


def slept():
    return _slept


def ns():
    return _ns


def now_us():
    # the clock as the simulator reads it: free, it is not the board's work
    return _now


def now_ms():
    # ticks_ms as the simulator reads it (free)
    return _ms


def ticks_us():
    if not free:
        charge_ns(simcost.READ_NS)
    return _now


def ticks_ms():
    if not free:
        charge_ns(simcost.READ_NS)
    return _ms


def ticks_cpu():
    return ticks_us()


def ticks_add(t, delta):
    # As the port's (extmod/modtime.c): a delta ticks_diff could not give back, |delta| >= 2^29,
    # is an OverflowError, not a wrap (a board that asks for one has a bug: it must show here)
    kind = type(delta)
    if kind is not int and kind is not bool:  # (MicroPython: a bool is no int; no tuple a call)
        raise TypeError("can't convert %s to int" % kind.__name__)
    if delta >= TICKS_HALF or delta <= -TICKS_HALF:
        if delta > _WORD_MAX or delta < -_WORD_MAX:  # (a 32-bit board's word, as the port sees it)
            raise OverflowError("overflow converting long int to machine word")
        raise OverflowError("ticks interval overflow")
    return _wrap_add(t, delta)


def _wrap_add(t, delta):
    # t + delta wrapped, without the sum past TICKS_MAX (a long integer) that (t + delta) &
    # TICKS_MAX would make at the wrap
    t &= TICKS_MAX
    d = delta & TICKS_MAX
    room = TICKS_MAX - t
    return d - room - 1 if d > room else t + d


def ticks_diff(a, b):
    d = (a - b) & TICKS_MAX
    return d - TICKS_MAX - 1 if d >= TICKS_HALF else d


def sleep_us(us):
    advance(int(us))


def sleep_ms(ms):
    advance(int(ms) * 1000)


def sleep(s):
    advance(int(s * 1000000))


def time():
    return _s


def time_ns():
    return ((_s * 1000 + _ms_in_s) * 1000 + _sub) * 1000 + _ns
