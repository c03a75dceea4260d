# The board's filesystem as MicroPython on a board has it: this port's VfsPosix over a directory
# of the runtime, mounted at / behind a proxy that raises MicroPython's errno numbers (a board's
# littlefs or FAT raises OSError(2) for a missing file; this port raises the runtime's own, 44),
# which mpremote reads (ENOENT: copy it; EEXIST: the directory is there).
import os

import vfs

# Emscripten's errno -> MicroPython's (py/mperrno.h, the numbers of Linux)
_ERRNO = {63: 1, 44: 2, 29: 5, 8: 9, 2: 13, 20: 17, 54: 20, 31: 21, 28: 22, 51: 28, 55: 39}


def _mp(e):
    return OSError(_ERRNO.get(e.errno, e.errno))


class BoardFs:
    def __init__(self, root):
        self.fs = vfs.VfsPosix(root)

    def mount(self, readonly, mkfs):
        self.fs.mount(readonly, mkfs)

    def umount(self):
        self.fs.umount()

    def ilistdir(self, path):
        try:
            return iter(list(self.fs.ilistdir(path)))
        except OSError as e:
            raise _mp(e)

    def chdir(self, path):
        try:
            return self.fs.chdir(path)
        except OSError as e:
            raise _mp(e)

    def getcwd(self):
        return self.fs.getcwd()

    def mkdir(self, path):
        try:
            return self.fs.mkdir(path)
        except OSError as e:
            raise _mp(e)

    def remove(self, path):
        try:
            return self.fs.remove(path)
        except OSError as e:
            raise _mp(e)

    def rename(self, old, new):
        try:
            return self.fs.rename(old, new)
        except OSError as e:
            raise _mp(e)

    def rmdir(self, path):
        try:
            return self.fs.rmdir(path)
        except OSError as e:
            raise _mp(e)

    def stat(self, path):
        try:
            return self.fs.stat(path)
        except OSError as e:
            raise _mp(e)

    def statvfs(self, path):
        return self.fs.statvfs(path)

    def open(self, path, mode):
        try:
            return self.fs.open(path, mode)
        except OSError as e:
            raise _mp(e)


vfs.umount("/")
vfs.mount(BoardFs("/flash"), "/")
os.chdir("/")  # (relative paths, as mpremote's, resolve on the mount, not the one it replaced)
