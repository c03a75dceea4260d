"""``serial:///dev/ttyACM0?baud=115200``: UARTs, USB CDC-ACM boards, pseudo-terminals (pyserial).

DTR: an Arduino-class board resets when DTR is asserted (its auto-reset capacitor).  Linux
asserts DTR when a port is opened, before any program can say otherwise, and drops it on close
when HUPCL is set (the default).  The port is opened with DTR asserted as the kernel leaves it
(pyserial's default, no extra toggle) and HUPCL is cleared at once: closing the port leaves DTR
where it is, so the next open (a reconnect, or the daemon after discovery's probe) makes no edge
and resets nothing.  The first open of a freshly plugged board still resets it; that one the OS
does not let a program keep.
"""

from __future__ import annotations

import errno
import os
import termios
from urllib.parse import unquote, urlsplit

import serial

from ..errors import BadURL, TransportBroken
from ..text import clean
from .base import FdTransport

DEFAULT_BAUD = 115200


class SerialTransport(FdTransport):
    def __init__(self, url: str, port: serial.Serial) -> None:
        super().__init__(url, port.fileno())
        self.port = port
        if port.write_timeout:  # (the descriptor is non-blocking: FdTransport.write waits)
            self.write_timeout = port.write_timeout

    def _recv(self, n: int) -> tuple[bytes, int]:
        try:
            data: bytes = self.port.read(max(1, min(n, self.port.in_waiting)))
        except serial.SerialException as e:
            # pyserial says "device reports readiness to read but returned no data" when the
            # other end of a pty or an unplugged USB serial device is gone.
            raise OSError(str(e)) from e
        return data, 0  # (no stamp of the driver's: the caller's, or the byte count's)

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._wake_reader()
            try:
                self.port.close()
            except (OSError, serial.SerialException):  # (gone already: closing must not fail)
                pass


def open_serial(url: str, query: dict[str, str]) -> SerialTransport:
    path = unquote(urlsplit(url).path)
    if not path:
        raise BadURL(f"{url!r}: expected serial:///dev/DEVICE[?baud=N]")
    try:
        baud = int(query.get("baud", DEFAULT_BAUD))
    except ValueError as e:
        raise BadURL(f"{url!r}: baud must be a number, not {query.get('baud')!r}") from e
    try:
        port = serial.Serial(path, baudrate=baud, timeout=0, write_timeout=2.0, exclusive=True)
    except (serial.SerialException, OSError, ValueError) as e:
        raise TransportBroken(f"{url}: {cannot_open(path, e)}") from e
    keep_dtr(port.fileno())
    # Whatever the board sent before we opened the port (samples nobody read) is stale.
    port.reset_input_buffer()
    return SerialTransport(url, port)


def cannot_open(path: str, e: BaseException) -> str:
    """Why ``path`` did not open, in one line: pyserial's own text repeats the errno and the
    path ("[Errno 2] could not open port /dev/x: [Errno 2] No such file or directory: '/dev/x'");
    a port another process holds (its exclusive lock) names that process."""
    code = getattr(e, "errno", None)
    if "exclusively lock" in str(e) or code in (errno.EAGAIN, errno.EBUSY):
        who = holders(path)
        runs = [w for w in who if w.split(": ", 1)[1].startswith("missing-link run")]
        if runs:  # (a pty's other end has it open too: the board, not the one that locked it)
            return f"{path} is held by another missing-link run ({'; '.join(runs)})"
        return f"{path} is held by another process ({'; '.join(who) or 'not one of yours'})"
    if code == errno.ENOENT:
        return f"cannot open {path}: no such device (unplugged? another name?)"
    if code == errno.EACCES:
        return f"cannot open {path}: permission denied (the dialout group: docs/hardware.md)"
    return f"cannot open {path}: {os.strerror(code) if code else e}"


def holders(path: str, limit: int = 4) -> list[str]:
    """The processes (of this user: /proc shows only theirs) that have ``path`` open, each as
    "pid 123: missing-link run serial:///dev/ttyACM0"."""
    try:
        target = os.path.realpath(path)
        pids = [p for p in os.listdir("/proc") if p.isdigit() and int(p) != os.getpid()]
    except OSError:
        return []
    found = []
    for pid in pids:
        try:
            fds = os.listdir(f"/proc/{pid}/fd")
            if any(os.readlink(f"/proc/{pid}/fd/{fd}") == target for fd in fds):
                with open(f"/proc/{pid}/cmdline", "rb") as f:
                    found.append(f"pid {pid}: {_command(f.read())}")
        except OSError:  # (gone, or not ours)
            continue
        if len(found) == limit:
            break
    return found


def _command(cmdline: bytes) -> str:
    """A process's command line as a user reads it: ``missing-link run URL`` rather than the
    interpreter's path and ``-m missing_link``."""
    words = [w.decode(errors="replace") for w in cmdline.split(b"\0") if w]
    for k, w in enumerate(words):
        if w.endswith("missing-link") or (w == "missing_link" and k and words[k - 1] == "-m"):
            words = ["missing-link", *words[k + 1 :]]
            break
    return clean(" ".join(words))[:120]


def keep_dtr(fd: int) -> None:
    """Clear HUPCL: closing the port then leaves DTR (and RTS) as they are (see above)."""
    try:
        attrs = termios.tcgetattr(fd)
        if attrs[2] & termios.HUPCL:
            attrs[2] &= ~termios.HUPCL
            termios.tcsetattr(fd, termios.TCSANOW, attrs)
    except termios.error:  # not a tty after all (a test double): nothing to keep
        pass
