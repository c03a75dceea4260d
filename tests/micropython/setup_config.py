# Runs on MicroPython (and, with mlboard = missing_link.board, on CPython): the board of the
# run-time configuration's golden vectors (tests/vectors.py CONFIG_VECTORS), its record saved
# to a real file on the interpreter's filesystem, and power cuts in the middle of a save.
#
# Lines: hex = bytes from the host (answered with the board's output); "REBOOT" builds the board
# again from the same filesystem; "CUT n" makes the next save lose power after n bytes of the
# new record reached the file; "CUTRENAME" after the whole record, before the rename.
import struct
import sys

import mlboard.config as C
import mlboard.store as S
from mlboard.runtime import BoardRuntime, Transducer

PATH = globals().get("CONFIG_PATH", "/mlconfig-test.bin")  # (CPython tests: a tmp file)


class Rate:
    # A driver with every kind of key: a rate, a mode (enum), a read-only gain, and a
    # combination it refuses (slow mode above 10 Hz), so a set is all or nothing.
    CONFIG = (
        ("rate_hz", "float", (0.1, 1000.0), False),
        ("mode", "enum", ("fast", "slow"), False),
        ("gain", "int", (1, 8), True),
    )

    def __init__(self):
        self.v = {"rate_hz": 100.0, "mode": "fast", "gain": 2}

    def get_config(self, key):
        return self.v[key]

    def set_config(self, key, value):
        self.v[key] = value

    def check_config(self):
        if self.v["mode"] == "slow" and self.v["rate_hz"] > 10:
            return "slow mode goes up to 10 Hz"
        return None


class PowerCut(BaseException):
    # the board stops where it is: nothing of the runtime catches this (it is not an Exception)
    pass


class _CutFile:
    def __init__(self, f, left):
        self.f = f
        self.left = left

    def write(self, data):
        if self.left is not None and len(data) > self.left:
            self.f.write(data[: self.left])
            self.f.close()
            raise PowerCut()
        return self.f.write(data)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.f.close()


class _CutOs:
    def __init__(self, os_module):
        self.os = os_module

    def rename(self, a, b):
        raise PowerCut()

    def remove(self, p):
        self.os.remove(p)


_cut = None  # None, ("bytes", n) or ("rename",)


def _open(path, mode="r"):
    f = open(path, mode)
    if _cut is not None and _cut[0] == "bytes" and "w" in mode:
        return _CutFile(f, _cut[1])
    return f


def make_store():
    store = S.FileStore(PATH)
    if _cut is not None and _cut[0] == "rename":
        store.os = _CutOs(store.os)
    return store


def boot():
    rt = BoardRuntime("v", "config vectors", "cfg-1", epoch="e1", clock=lambda: 1000)
    rt.add_transducer(Transducer("signal", 0, "counter", "COUNTER", 1, "int32_t", -1), Rate())
    rt.config = C.RuntimeConfig(rt, make_store())
    return rt


S.open = _open  # (a power cut is armed only by CUT lines)
rt = boot()


def _ident():
    version = ".".join(str(v) for v in sys.implementation.version[:3])
    return "%s %s" % (sys.implementation.name, version)


def _step(h):
    global rt, _cut
    if h == "REBOOT":
        _cut = None
        rt = boot()
        return ""
    if h.startswith("CUT"):
        _cut = ("rename",) if h == "CUTRENAME" else ("bytes", int(h.split()[1]))
        rt.config.store = make_store()  # (the same file)
        return ""
    try:
        rt.feed(bytes.fromhex(h))
    except PowerCut:
        return "CUT"
    rt.poll()
    return rt.take_output().hex()


_ = struct  # (MicroPython: imported for the host's convenience in ctl lines)
