"""Test code tests/test_world_beside.py runs in the MicroPython simulator (sim.ctl): the faults
a world in the firmware would bring, on the parts the world feeds (worldfeed.py), to show the
figures catch them, and FEED_HEAP, which counts the heap allocated where the world's feed calls
run.  Python source as text: it runs there, not here."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from missing_link.deploy.boardfile import load_board_file

ROVER = Path(__file__).resolve().parent.parent / "examples" / "boards" / "rover.py"
BOARD: dict[str, Any] = load_board_file(ROVER).board

#: Faults a world in the firmware would bring (test code run in the simulator, on the parts the
#: world feeds: worldfeed.py), to show the figures catch them.  GARBAGE: each IMU feed leaves
#: 64 B of the board's heap behind (a world whose feed's values were objects there).
GARBAGE = """
import simworld.worldfeed as f
class _Feed:
    def __init__(s, d):
        s.d = d
    @property
    def accel(s):
        s.junk = bytearray(64)
        return s.d.accel
    @property
    def gyro(s):
        return s.d.gyro
for i in range(f.MAX_PARTS):
    if f._kinds[i] == f.IMU and f._devs[i] is not None:
        f._devs[i] = _Feed(f._devs[i])
"""
#: HOLD: each IMU read holds the firmware 300 µs more (a world's hand in the part charged to
#: the board's time: the firmware's own work, inside its step)
HOLD = """
import simworld.worldfeed as f, simworld.simtime as s
def _held(d):
    read = d.read
    def held(reg, n):
        s.advance(300)
        return read(reg, n)
    d.read = held
for i in range(f.MAX_PARTS):
    if f._kinds[i] == f.IMU and f._devs[i] is not None:
        _held(f._devs[i])
"""
#: FLOAT: each IMU feed leaves one float (16 B) behind: 0.38 % of the run's allocation, within
#: ALLOCATED and the runs' own spread; the heap allocated between the steps holds it (FEED_HEAP)
FLOAT = GARBAGE.replace("bytearray(64)", "getattr(s, 'junk', 0.0) + 0.5")
#: EDGE: the encoders' edge handlers allocate 16 B an edge (an edge's path in the board's heap)
ENCODER_PINS = tuple(
    t[k] for t in BOARD["transducers"] if t["driver"] == "quadrature" for k in ("pin_a", "pin_b")
)
EDGE = f"""
from simworld.machine import WORLD
def _alloc(h):
    def held(p):
        WORLD.junk = bytearray(16)
        return h(p)
    return held
for p in {ENCODER_PINS}:
    st = WORLD.pin(p)
    if st.handler is not None:
        st.handler = _alloc(st.handler)
"""
#: FEED_HEAP: the heap allocated between the firmware's steps, where the world's feed calls
#: and its edges (worldfeed.py, steps_at, the firmware's handlers) run and nothing else does
#: but the host's bytes (a step's input string: those steps counted apart) and a test's
#: requests: from a step's end (after its collection, if one ran) to the next one's start
#: (mpyhost._step: simtime.set_now with two arguments, an edge's has one), read as the
#: simulator's scans (simgc's _gc.mem_alloc: no board time).  Small integers only: 0.
FEED_HEAP = """
import simworld.simgc as G, simworld.simtime as S, simworld.mpyhost as H
_mem = G._gc.mem_alloc
R = [-1, -1, 0, 0, 0, 0, 0, 0]  # base, this gap, host's bytes, then the figures (Run)
_sn, _es, _st, _fd, _cl = S.set_now, G.end_step, G.settle, H._feed, H._closed
def _set_now(us, ns=-1):
    if ns < 0:
        return _sn(us)  # (an edge's time)
    R[1] = _mem() - R[0] if R[0] >= 0 else -1
    R[2] = 0
    _sn(us, ns)
def _feed(n, h):
    R[2] = 1
    return _fd(n, h)
def _closed(n):
    R[2] = 1
    return _cl(n)
def _end_step():
    if R[1] >= 0 and R[2]:
        R[6] += R[1]
        R[7] += 1
    elif R[1] >= 0:
        R[3] += R[1]
        R[4] += 1
        R[5] = max(R[5], R[1])
    R[0] = _mem()
    return _es()
def _settle():
    took = _st()
    R[0] = _mem()
    return took
S.set_now, G.end_step, G.settle, H._feed, H._closed = _set_now, _end_step, _settle, _feed, _closed
H.FEED_HEAP = R
"""
#: the driven runs: each motor's duty each turn (the host's command: failsafe_ms 300), 0.5 and
#: then -0.3 from the middle on (the actuators change: the world's batch cut there)
DUTIES = (0.5, -0.3)
