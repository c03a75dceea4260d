# Runs on MicroPython: a Part 2 board (a2jClock, a2jHostMap) built from the unchanged runtime,
# with setTriggerAt-style use of the host's map: "boardTimeAt" answers the board tick for a
# host time, in integer maths (MicroPython floats may be 32 bit).
import struct
import sys

from mlboard.runtime import BoardRuntime

rt = BoardRuntime("mpy2", "wasm", "mpy-2", epoch="e2")


def _board_time_at(p):
    at = rt.board_time_at(struct.unpack("<q", p)[0])
    if at is None:
        return 0xFF, b""
    return 0, struct.pack("<Q", at)


rt.add_function("boardTimeAt", _board_time_at)


def _ident():
    version = ".".join(str(v) for v in sys.implementation.version[:3])
    return "%s %s clock=%s" % (sys.implementation.name, version, type(rt.clock).__name__)


def _step(h):
    rt.feed(bytes.fromhex(h))
    rt.poll()
    return rt.take_output().hex()
