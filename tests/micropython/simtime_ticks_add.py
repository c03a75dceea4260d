# ruff: noqa: E402, I001  (MicroPython: the simulator's modules are found in /lib)
# time.ticks_add of the port (real MicroPython) and simtime.ticks_add (the simulated board's
# clock, --fast) called alike: run(t, delta), each a Python expression, prints one JSON line,
# what each returned or raised (the exception's type and message).  Run by simworld.mjs.
import sys

sys.path.append("/lib")
import simworld.simtime as simtime
import time
import json


def _call(f, t, delta):
    try:
        return ["=", f(t, delta)]
    except (OverflowError, TypeError) as e:  # what either may raise, compared
        return [type(e).__name__, str(e)]


def run(t, delta):
    t, delta = eval(t), eval(delta)
    port, sim = _call(time.ticks_add, t, delta), _call(simtime.ticks_add, t, delta)
    print(json.dumps({"port": port, "sim": sim}))
