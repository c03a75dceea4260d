# Runs on MicroPython: the golden-vector board of docs/protocol.md (original function table),
# built from the unchanged board runtime.  _step() is one turn of the board's process loop.
import struct
import sys

from mlboard.runtime import BoardRuntime, Transducer

rt = BoardRuntime("mpy", "wasm", "mpy-1", epoch="e1", part2=False)
rt.add_function("getTime", lambda p: (0, struct.pack("<Q", rt.clock())))
rt.add_function("syncTime", lambda p: (0, b""))
_blob = bytes((i * 7 + 3) & 0xFF for i in range(1000))
rt.add_blob_function("bigBlob", lambda: _blob)


class Pulse:
    def set_cb(self, fn):
        self.fn = fn


pulse = Pulse()
rt.add_transducer(Transducer("quad", 13, "quad", "HEDS-6500", 1, "int16_t", -1), pulse)


def _ident():
    version = ".".join(str(v) for v in sys.implementation.version[:3])
    return "%s %s clock=%s" % (sys.implementation.name, version, type(rt.clock).__name__)


def _step(h):
    if h.startswith("PULSE"):
        pulse.fn(0, int(h[5:]))
    else:
        rt.feed(bytes.fromhex(h))
    rt.poll()
    return rt.take_output().hex()
