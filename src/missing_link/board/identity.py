# Who a board is and what it runs: the properties board.id and fw.hash (docs/hardware.md,
# "Identity").
#
# board.id is stable and unique: on MicroPython the chip's own machine.unique_id() (in hex), on
# a virtual board its seed (or the directory standing for its flash), on AVR a serial written
# into the EEPROM at flash time (firmware/avr/src/identity.c).  fw.hash says which firmware
# runs: the first 16 hex digits of a SHA-256 over the runtime's files and the board file, each as
#
#     path "\0" size "\0" bytes          (path relative to the runtime's folder, "/"-separated;
#                                         the board file's is "board.py")
#
# in the order of their paths.  The board file is part of the firmware, as its tables are of an
# AVR image: an update that changes a rate changes the hash (board/update.py).  The board hashes
# the files it has (its lib/mlboard and the board file it imported, read in chunks: a board has
# little RAM); `missing-link flash` hashes the same files before it copies them, and compares
# after the reset (deploy/flash.py).  Only .py files count: what MicroPython runs (no
# __pycache__).
#
# MicroPython subset: hashlib.sha256 and os.listdir/os.stat, nothing else.

import hashlib
import os
import sys

HASH_DIGITS = 16
BOARD_FILE = "board.py"  # the board file's path in the hash
_CHUNK = 512
_DIR = 0x4000  # S_IFDIR in os.stat()[0], on MicroPython and CPython


def hex_id(raw):
    # machine.unique_id() (bytes) as the text of board.id
    return "".join("%02x" % b for b in raw)


def machine_id(machine):
    # the chip's own id, or "" on a port without one (the board file may name a serial then)
    try:
        return hex_id(machine.unique_id())
    except Exception:  # noqa: BLE001 - a port without unique_id
        return ""


class FirmwareHash:
    # add(path, size, chunks) for each file, in any order; digest() -> the fw.hash text.  The
    # files are hashed in the order of their paths, so adding them in another order is the same.
    def __init__(self):
        self._files = []

    def add(self, path, size, chunks):
        # chunks: an iterable of bytes whose total length is size
        self._files.append((path, size, chunks))

    def digest(self):
        h = hashlib.sha256()
        for path, size, chunks in sorted(self._files, key=lambda f: f[0]):
            h.update(path.encode() + b"\0" + str(size).encode() + b"\0")
            n = 0
            for chunk in chunks:
                h.update(chunk)
                n += len(chunk)
            if n != size:
                raise ValueError("%s: %d bytes read, %d expected" % (path, n, size))
        return hex_id(h.digest())[:HASH_DIGITS]


def _file_chunks(path, buf, view):
    # (into one buffer for the whole tree: a board hashes its runtime at boot, and a chunk read
    # anew each time is as much garbage as the runtime's size, in a heap not much bigger; the
    # files are read one after the other, digest() done with each chunk before the next)
    with open(path, "rb") as f:
        while True:
            n = f.readinto(buf)
            if not n:
                return
            yield view[:n]


def _walk(root, rel, out, buf, view):
    for name in sorted(os.listdir(root + "/" + rel if rel else root)):
        path = (rel + "/" + name) if rel else name
        full = root + "/" + path
        st = os.stat(full)
        if st[0] & _DIR:
            if not name.startswith("__pycache__"):
                _walk(root, path, out, buf, view)
        elif name.endswith(".py"):
            out.add(path, st[6], _file_chunks(full, buf, view))


def tree_hash(root, board_file=None):
    # fw.hash of the runtime files under root (a folder: the board's lib/mlboard) and the board
    # file at board_file (None: a runtime without one, a virtual board's)
    out = FirmwareHash()
    buf = bytearray(_CHUNK)
    view = memoryview(buf)
    _walk(root, "", out, buf, view)
    if board_file is not None:
        out.add(BOARD_FILE, os.stat(board_file)[6], _file_chunks(board_file, buf, view))
    return out.digest()


def board_file_path():
    # the file of the board file module this firmware imported (`board`), or None
    mod = sys.modules.get("board")
    path = getattr(mod, "__file__", None)
    return path if isinstance(path, str) and path.endswith(".py") else None


_cached = []


def runtime_hash():
    # fw.hash of this runtime, as it runs here (the folder of this module), and of the board
    # file it runs, once per boot; "" where it cannot be read (frozen into the firmware image:
    # no files)
    if not _cached:
        try:
            here = __file__.replace("\\", "/")
            _cached.append(tree_hash(here[: here.rfind("/")], board_file_path()))
        except (OSError, NameError, ValueError):
            _cached.append("")
    return _cached[0]
