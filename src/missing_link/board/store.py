# Where a board keeps its saved configuration (config.py): a record in a file.  The shell's
# storage, so the runtime itself stays free of I/O.
#
# MicroPython subset only.


class FileStore:
    # A configuration record in a file: written under a temporary name, then renamed over the
    # old one (atomic on littlefs and on POSIX): a power cut leaves the old or the new record.
    def __init__(self, path, os_module=None):
        if os_module is None:
            import os as os_module  # (injected by tests that cut the power)
        self.os = os_module
        self.path = path
        self.tmp = path + ".tmp"

    def read(self):
        # (a write that died between its two steps on FAT, below, left only the new record)
        for path in (self.path, self.tmp):
            try:
                with open(path, "rb") as f:
                    return f.read()
            except OSError:
                pass
        return None

    def write(self, record):
        with open(self.tmp, "wb") as f:
            f.write(record)
        try:
            self.os.rename(self.tmp, self.path)
        except OSError:  # FAT will not rename over a file: remove it first (read() copes)
            self.os.remove(self.path)
            self.os.rename(self.tmp, self.path)

    def erase(self):
        try:
            self.os.remove(self.path)
        except OSError:
            pass
