"""The transport interface: a byte link to one board, and the base of every link that is a file
descriptor (socket, pty, serial port).  URLs are resolved by :mod:`.registry`."""

from __future__ import annotations

import fcntl
import os
import select
import struct
import termios
import threading
import time
from abc import abstractmethod

from ..closing import Closing
from ..errors import TransportBroken, TransportClosed

#: what a stamped read returns: ``(data, rx_ns, first_rx_ns)`` (:meth:`Transport.read_stamped`)
Received = tuple[bytes, int, int]


class Transport(Closing):
    """A byte link to one board.  Thread rules: one reader thread, writes from any thread."""

    url: str = ""

    @abstractmethod
    def read(self, timeout: float | None) -> bytes:
        """Bytes that arrived, waiting at most ``timeout`` seconds; b"" when none came.
        Raises TransportBroken when the peer went away, TransportClosed after close()."""

    def read_stamped(self, timeout: float | None) -> Received:
        """:meth:`read`, with when the bytes came: ``(data, rx_ns, first_rx_ns)``.

        ``rx_ns``: CLOCK_MONOTONIC ns by which every byte of ``data`` had arrived: right after
        the read returned, or earlier where the transport knows better (TCP: the kernel's
        receive stamp of the last segment the read took; the byte count at the wake-up, see
        ``count_arrived``).  Never before the bytes arrived, so clock sync's t4 is a valid
        upper constraint (the same user-space layer a board's shell stamps t2 at).

        ``first_rx_ns``: by when the *first* byte had arrived, when that is known and earlier:
        the wait that said the descriptor was readable returned then, and nothing read it in
        between, so whatever came first was there.  A reply that heads the read was on its
        way by then (t4 without the host's work between its wake-up and the byte count).
        Known only while ``count_arrivals``; else 0.

        Both 0 when the transport does not stamp (the caller stamps after the read); this
        default stamps nothing."""
        return self.read(timeout), 0, 0

    @abstractmethod
    def write(self, data: bytes) -> None:
        """Send all of ``data``; raises TransportBroken / TransportClosed."""

    #: CLOCK_MONOTONIC ns just before the newest write reached the OS (clock sync's t1); 0
    #: when the transport does not stamp (the caller's stamp is used)
    last_write_ns: int = 0
    #: set by the board while a clock exchange is in flight: the reader then counts the bytes
    #: waiting the moment its wait returns (``count_arrived``), for a tighter t4 (and a TCP
    #: link asks the kernel for its receive stamps)
    count_arrivals: bool = False
    #: close() and poke() wake a read() that is waiting: a reader may then wait long when idle
    wakes_on_close: bool = False

    def poke(self) -> None:
        """Make a waiting read() return b"" now (the caller has new timers for the reader)."""

    def count_arrived(self, woke_ns: int = 0) -> None:
        """Right after a wait said bytes are there (it returned at ``woke_ns``): note how many,
        and when (see FdTransport)."""

    def link_stats(self) -> dict[str, int]:
        """What the link itself counts, by name (a signed link: the records it dropped); {}"""
        return {}

    def write_frames(self, frames: list[bytes]) -> None:
        """Send whole frames.  Stream links join them; USB sends one transfer per frame."""
        if frames:
            self.write(b"".join(frames))

    @abstractmethod
    def close(self) -> None:
        """Idempotent."""

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.url}>"


class FdTransport(Transport):
    """A transport over a readable/writable file descriptor (socket, pty, serial port)."""

    wakes_on_close = True
    #: s a write waits for room in a full buffer, the board reading nothing, before it fails
    write_timeout = 2.0

    def __init__(self, url: str, fd: int) -> None:
        self.url = url
        self._fd = fd
        self._closed = False
        # (bytes, when counted, when the wait returned): see count_arrived
        self._counted: tuple[int, int, int] | None = None
        self._wlock = threading.Lock()
        # close() writes here, so a reader blocked in select() returns at once
        self._wake_r, self._wake_w = os.pipe()

    def _wake_reader(self) -> None:
        """Subclasses call this from close(), after marking the transport closed."""
        self.poke()

    def poke(self) -> None:
        try:
            os.write(self._wake_w, b"x")
        except OSError:  # (full: poked already; or released)
            pass

    def release(self) -> None:
        """Close the wake pipe once nothing reads this transport any more (its reader ended):
        not in close(), where a reader may still be waiting on the pipe."""
        for name in ("_wake_r", "_wake_w"):
            fd = getattr(self, name, -1)
            if fd >= 0:
                setattr(self, name, -1)
                try:
                    os.close(fd)
                except OSError:  # (closed already)
                    pass

    def __del__(self) -> None:
        self.release()

    def _check(self) -> None:
        if self._closed:
            raise TransportClosed(f"{self.url}: transport closed on this side")

    def _recv(self, n: int) -> tuple[bytes, int]:
        """Up to ``n`` bytes, and an earlier CLOCK_MONOTONIC ns by which all of them had
        arrived when the link knows one (TCP: the kernel's receive stamp), else 0."""
        return os.read(self._fd, n), 0

    def count_arrived(self, woke_ns: int = 0) -> None:
        """Called the moment a wait said this descriptor is readable (it returned at
        ``woke_ns``), while a clock exchange is in flight: the bytes waiting now (FIONREAD) had
        all arrived by now, so the next ``read_ready`` takes exactly those and stamps them with
        this moment (t4), not with the end of the loop's work and the read that follow; and
        the first of them had arrived by ``woke_ns`` (the read's ``first_rx_ns``)."""
        try:
            raw = fcntl.ioctl(self._fd, termios.FIONREAD, b"\0\0\0\0")
        except (OSError, ValueError):  # closed meanwhile: the read reports it
            return
        n = struct.unpack("i", raw)[0]
        if n > 0:  # (the first 64 KiB of many were there too: one read's worth)
            now = time.monotonic_ns()
            self._counted = (min(n, 65536), now, woke_ns if 0 < woke_ns <= now else 0)

    def _send(self, data: memoryview) -> int:
        return os.write(self._fd, data)

    def fileno(self) -> int:
        """The descriptor a shared I/O loop (missing_link.host.reactor) waits on."""
        return self._fd

    def read(self, timeout: float | None) -> bytes:
        return self.read_stamped(timeout)[0]

    def read_stamped(self, timeout: float | None) -> Received:
        self._check()
        try:
            ready, _, _ = select.select([self._fd, self._wake_r], [], [], timeout)
        except (OSError, ValueError, TypeError) as e:
            self._check()
            raise TransportBroken(f"{self.url}: read failed: {e}") from e
        if self._closed:
            raise TransportClosed(f"{self.url}: transport closed on this side")
        if self._wake_r in ready:
            os.read(self._wake_r, 64)  # a poke: the reader has new timers to look at
        if self._fd not in ready:
            return b"", 0, 0
        if self.count_arrivals:
            self.count_arrived(time.monotonic_ns())
        return self.read_ready()

    def read_ready(self) -> Received:
        """Read what arrived on a descriptor that a wait said is readable (never blocks):
        ``(data, rx_ns, first_rx_ns)`` as :meth:`read_stamped` says."""
        self._check()
        counted, self._counted = self._counted, None
        try:
            data, arrived = self._recv(65536 if counted is None else counted[0])
            # After the read, never before it: between select() returning and the read, this
            # thread can wait for the interpreter lock while another writes a request whose
            # reply then comes back in this same read; a stamp taken before would be earlier
            # than the request (measured: 10 µs "round trips", clock-sync bounds broken).
            now = time.monotonic_ns()
        except (OSError, ValueError, TypeError) as e:  # TypeError: pyserial after close()
            self._check()
            raise TransportBroken(f"{self.url}: read failed: {e}") from e
        if not data:
            raise TransportBroken(f"{self.url}: the other side closed the link")
        # An earlier stamp by which every byte of this read had arrived (TCP: the kernel's
        # stamp of the last segment; else when count_arrived counted the bytes) is tighter and
        # still valid; never trust it beyond our own stamp.
        if counted is None:
            return data, arrived if 0 < arrived <= now else now, 0
        if arrived <= 0 or counted[1] < arrived:
            arrived = counted[1]  # (the read took at most the bytes counted then)
        return data, arrived if 0 < arrived <= now else now, counted[2]

    def write(self, data: bytes) -> None:
        """All of ``data``.  A descriptor whose buffer is full (a board that reads slower than
        this host writes: a UART, simavr's pty under load) takes the rest once it has room; one
        that takes nothing for ``write_timeout`` s fails the write (TransportBroken)."""
        self._check()
        view = memoryview(data)
        with self._wlock:
            self.last_write_ns = time.monotonic_ns()
            try:
                while view:
                    try:
                        n = self._send(view)
                    except BlockingIOError:  # (EAGAIN: a non-blocking descriptor, full)
                        self._wait_writable(len(view))
                        continue
                    view = view[n:]
            except (OSError, ValueError) as e:
                self._check()
                raise TransportBroken(f"{self.url}: write failed: {e}") from e

    def _wait_writable(self, left: int) -> None:
        """Until the descriptor has room again, at most ``write_timeout`` s (``left``: the
        bytes still to go, for the error).  A board that took some meanwhile is waited for
        again: a TCP socket is writable only once a third of its buffer is free, which a board
        reading slowly but steadily (its window opening a little at a time) may take longer than
        ``write_timeout`` to give; what it has taken is what left the output queue."""
        queued = self._queued()
        while True:
            _, ready, _ = select.select([], [self._fd], [], self.write_timeout)
            self._check()
            if ready:
                return
            now = self._queued()
            if queued is None or now is None or now >= queued:
                raise TransportBroken(
                    f"{self.url}: write failed: the board took nothing for "
                    f"{self.write_timeout:g} s ({left} bytes not sent: its input is full, it "
                    "reads no more)"
                )
            queued = now

    def _queued(self) -> int | None:
        """The bytes written that the other side has not taken yet (TIOCOUTQ: a socket's
        unacknowledged and unsent bytes, a tty's output queue); None where it cannot say."""
        try:
            raw = fcntl.ioctl(self._fd, termios.TIOCOUTQ, b"\0\0\0\0")
        except (OSError, ValueError):
            return None
        return int(struct.unpack("i", raw)[0])
