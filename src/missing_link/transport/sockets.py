"""``tcp://HOST:PORT`` and ``unix:///path`` links (virtual boards, serial-to-network bridges)."""

from __future__ import annotations

import socket
import struct
import sys
import time
from urllib.parse import urlsplit

from ..errors import BadURL, TransportBroken
from .base import FdTransport

CONNECT_TIMEOUT = 5.0


#: Linux SO_TIMESTAMPNS (= SCM_TIMESTAMPNS; Python's socket module does not name it): the kernel
#: stamps each arriving segment (CLOCK_REALTIME), and recvmsg hands back the stamp of the last
#: segment a read consumed
_SO_TIMESTAMPNS = 35
_CMSG_SPACE = socket.CMSG_SPACE(16) if hasattr(socket, "CMSG_SPACE") else 0


def enable_rx_stamps(sock: socket.socket) -> bool:
    """Ask the kernel to stamp each segment arriving on a TCP socket (Linux); False where it
    cannot.  Also sets TCP_NODELAY: frames are small and latency matters more than packets."""
    if sock.family not in (socket.AF_INET, socket.AF_INET6):
        return False
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    if sys.platform != "linux" or not _CMSG_SPACE:
        return False
    try:
        sock.setsockopt(socket.SOL_SOCKET, _SO_TIMESTAMPNS, 1)
    except OSError:
        return False
    return True


def recv_stamped(sock: socket.socket, n: int) -> tuple[bytes, int]:
    """``recv`` with the kernel's receive stamp of the last segment the read took (CLOCK_REALTIME
    ns; 0 when the kernel gave none): a stamp of when the bytes arrived, not of when this
    thread got round to reading them (what a microcontroller's receive interrupt gives)."""
    data, ancillary, _flags, _addr = sock.recvmsg(n, _CMSG_SPACE)
    for level, kind, raw in ancillary:
        if level == socket.SOL_SOCKET and kind == _SO_TIMESTAMPNS and len(raw) >= 16:
            sec, nsec = struct.unpack("qq", raw[:16])
            return data, sec * 1_000_000_000 + nsec
    return data, 0


class SocketTransport(FdTransport):
    def __init__(self, url: str, sock: socket.socket) -> None:
        sock.setblocking(True)
        self._kernel_stamps = enable_rx_stamps(sock)
        super().__init__(url, sock.fileno())
        self.sock = sock

    def count_arrived(self, woke_ns: int = 0) -> None:
        if not self._kernel_stamps:  # (with them, the kernel's stamp is earlier still)
            super().count_arrived(woke_ns)

    def _recv(self, n: int) -> tuple[bytes, int]:
        if not (self._kernel_stamps and self.count_arrivals):
            # No clock reply expected: our own stamp after the read is good enough for samples
            # (their times come from the board), and recv costs ~1 µs less than recvmsg here.
            return self.sock.recv(n), 0
        # When the bytes arrived, not when this thread got round to reading them: clock sync's
        # t4 without the host's wake-up and scheduling delay (the return trip's host share).
        data, stamp = recv_stamped(self.sock, n)
        if not stamp:
            return data, 0
        # realtime -> monotonic with the offset read now (NTP slews it by ppm at most)
        offset = time.clock_gettime_ns(time.CLOCK_REALTIME) - time.monotonic_ns()
        return data, stamp - offset

    def _send(self, data: memoryview) -> int:
        # (never blocks: a full buffer is BlockingIOError, and write() waits write_timeout)
        return self.sock.send(data, socket.MSG_DONTWAIT)

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._wake_reader()
            try:
                self.sock.shutdown(socket.SHUT_RDWR)
            except OSError:  # (not connected any more: closed below all the same)
                pass
            self.sock.close()


def parse_host_port(
    url: str, usage: str = "expected tcp://HOST:PORT", schemes: tuple[str, ...] = ("tcp",)
) -> tuple[str, int]:
    """``tcp://HOST:PORT`` -> (HOST, PORT), for whoever opens, listens on or dials one; BadURL
    ``'URL': usage`` (what the caller takes) for another scheme, no host or no port."""
    parts = urlsplit(url)
    try:
        port = parts.port
    except ValueError as e:
        raise BadURL(f"{url!r}: bad port ({e}); {usage}") from None
    if parts.scheme not in schemes or not parts.hostname or port is None:
        raise BadURL(f"{url!r}: {usage}")
    return parts.hostname, port


def open_tcp(url: str, query: dict[str, str]) -> SocketTransport:
    host, port = parse_host_port(url)
    try:
        sock = socket.create_connection((host, port), timeout=CONNECT_TIMEOUT)
    except OSError as e:
        raise TransportBroken(f"{url}: cannot connect: {e}") from e
    return SocketTransport(url, sock)


def open_unix(url: str, query: dict[str, str]) -> SocketTransport:
    path = urlsplit(url).path
    if not path:
        raise BadURL(f"{url!r}: expected unix:///path/to/socket")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        sock.settimeout(CONNECT_TIMEOUT)
        sock.connect(path)
    except OSError as e:
        sock.close()
        raise TransportBroken(f"{url}: cannot connect: {e}") from e
    return SocketTransport(url, sock)
