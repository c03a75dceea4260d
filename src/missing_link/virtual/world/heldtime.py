"""The board's clock in real time with a world beside the firmware (host.mjs --world-fds without
--fast): the port's own `time`, but for the moments the world delivers an encoder's edge
(worldfeed.py steps_at), when ticks_us reads that edge's time, as a board's interrupt handler
reads its clock when the edge comes.  worldtick.mjs puts it in sys.modules as `time` before the
firmware imports `time`.  The MicroPython subset only (imported on CPython it has the names,
None where CPython's `time` lacks them: nothing here runs there).
"""

import time as _time

held = None  # µs (wrapped as the port's): what ticks_us says while an edge is delivered

_port_us = getattr(_time, "ticks_us", None)
ticks_ms = getattr(_time, "ticks_ms", None)
ticks_add = getattr(_time, "ticks_add", None)
ticks_diff = getattr(_time, "ticks_diff", None)
ticks_cpu = getattr(_time, "ticks_cpu", None)
sleep = _time.sleep
sleep_ms = getattr(_time, "sleep_ms", None)
sleep_us = getattr(_time, "sleep_us", None)
time = _time.time
time_ns = getattr(_time, "time_ns", None)
localtime = getattr(_time, "localtime", None)
gmtime = getattr(_time, "gmtime", None)
mktime = getattr(_time, "mktime", None)


def ticks_us():
    return _port_us() if held is None else held


def port_us():
    # the port's clock, whatever is held (the world's time: worldtick.mjs)
    return _port_us()


def set_now(us):
    global held
    held = us


def release():
    global held
    held = None
