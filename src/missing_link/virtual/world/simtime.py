"""Simulated time for the simulator's fast mode (host.mjs --fast): a `time` module whose clock is
the simulation's, so ten simulated minutes need not take ten real ones.  host.mjs puts it in
sys.modules as `time` before anything imports `time`, so the firmware (board/clock.py), the
simulated machine and the devices all read it.  The MicroPython subset only.

Theory of operation
-------------------
The clock counts simulated µs, wrapping at TICKS_PERIOD as the RP2040 port's ticks_us does
(board/clock.py extends it to 64 bit, as on a board).  Between two firmware steps the host
sets it (set_now): it jumps over the time the firmware would have slept and adds what the step
cost (the interpreter's CPU time, and a garbage collection's after it: fastclock.mjs).  Within
a step it moves by the step's CPU time so far at each read (`cpu`, fastclock.mjs: as a board's
clock runs on while its loop works, so the firmware's turn-end reading, where it decides on a
collection, board/memory.py, is not stale by the turn's work), READ_US a read (a read takes time
on a board too, and code that waits for the clock to move, board/clock.py resolution_us, must
see it move), what a sleep slept (sleep_us, a pulse waited for: machine.time_pulse_us), and what
a collection took at a gc.collect() (simgc.py); the step's total (slept()) goes back to the host
with its output.
"""

TICKS_PERIOD = 1 << 30
TICKS_MAX = TICKS_PERIOD - 1
READ_US = 1

_now = 0  # simulated µs, wrapped
_slept = 0  # µs advanced within the current step
cpu = None  # fast mode: the step's CPU time so far, simulated µs (host.mjs: fastclock.mjs)
_worked = 0  # ... of it the clock has moved by


def set_now(us):
    # a new step begins at simulated µs `us` (wrapped): nothing slept in it yet
    global _now, _slept, _worked
    _now = us & TICKS_MAX
    _slept = 0
    _worked = 0


def advance(us):
    global _now, _slept
    if us > 0:
        _now = (_now + us) & TICKS_MAX
        _slept += us


def slept():
    return _slept


def _work():
    # the clock moves on by the step's CPU time so far: the firmware sees its turn take time
    global _worked
    w = cpu()
    if w > _worked:
        advance(w - _worked)
        _worked = w


def ticks_us():
    if cpu is not None:
        _work()
    advance(READ_US)
    return _now


def ticks_ms():
    if cpu is not None:
        _work()
    advance(READ_US)
    return (_now // 1000) & TICKS_MAX


def ticks_cpu():
    return ticks_us()


def ticks_add(t, delta):
    return (t + delta) & TICKS_MAX


def ticks_diff(a, b):
    d = (a - b) & TICKS_MAX
    return d - TICKS_PERIOD if d >= TICKS_PERIOD >> 1 else d


def sleep_us(us):
    advance(int(us))


def sleep_ms(ms):
    advance(int(ms) * 1000)


def sleep(s):
    advance(int(s * 1000000))


def time():
    return _now // 1000000


def time_ns():
    return _now * 1000
