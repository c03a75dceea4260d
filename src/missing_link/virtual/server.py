"""Serve a board runtime on a listener: ``tcp://127.0.0.1:PORT`` (0 = pick), ``unix:///path``,
``pty`` (a pseudo-terminal, opened by hosts as ``serial:///dev/pts/N``) or ``memory://NAME``.

The loop is the board's process loop: wait for input or the next driver deadline, feed, poll,
write.  Like a real board it never blocks on output: when the host does not read, output waits in
a bounded queue of whole frames; past its limit the oldest SIFs are dropped (counted), never a
reply and never part of a frame.
One host at a time; a second connection is refused (closed at once) until the first goes away.
A failed accept (out of descriptors: EMFILE, which ``board --count N`` can reach) is counted
(``accept_errors``, said once) and the listener rests a while (10 ms doubling to 1 s; the
connection waits in the backlog), the host that is there served meanwhile.
A host that connects as the last one closes is the next host, not a second one, even when the
last one's final bytes are still unread: they are read first, and its close behind them (for
``_HANDOVER_PASSES`` passes at most: a last host still sending then is there).  A
frame a host cut off as it went is forgotten: the next host's bytes start frames of their own.

With ``dial=True`` the board connects out to ``tcp://HOST:PORT`` instead (a daemon that runs
``run --listen``), and again with the firmware's own backoff whenever the connection ends: the
same state machine as a MicroPython board that dials (board/dial.py).
"""

from __future__ import annotations

import errno
import itertools
import logging
import os
import select
import socket
import threading
import time
import tty
from collections import deque
from collections.abc import Callable
from urllib.parse import urlsplit

from ..board.dial import DialServer
from ..board.link import SocketNet
from ..board.runtime import BoardRuntime
from ..errors import TransportBroken, TransportClosed
from ..transport.in_process import MemoryListener, MemoryTransport
from ..transport.sockets import enable_rx_stamps, recv_stamped
from .listen import AcceptFailures, dial_address, listen_socket

OUT_LIMIT = 64 * 1024
_WRITE_CHUNK = 16 * 1024
_MAX_WAIT = 0.05
_HANDOVER_READ = 64 * 1024  # what a host that connects waits behind (see _handover)
_HANDOVER_PASSES = 16  # ... for at most this many passes (1 MiB; at most 0.8 s), then turned away

log = logging.getLogger(__name__)


class _Link:
    """One connected host: a non-blocking fd (socket or pty master) plus an output queue of
    whole frames.  When the host does not read, the oldest *SIFs* are dropped (counted) to keep
    the queue under ``OUT_LIMIT``; a reply is never dropped (a host waits for it)."""

    def __init__(self, fd: int, sock: socket.socket | None = None) -> None:
        self.fd = fd
        self.sock = sock
        # Over TCP the kernel stamps each segment as it arrives: the board's t2 is then when
        # the request arrived, as a microcontroller stamps it in its receive interrupt, not when
        # this process woke up (the host stamps its t4 the same way: the two directions match).
        self.kernel_stamps = sock is not None and enable_rx_stamps(sock)
        self.arrived_age_ns = 0  #: how long ago (ns) the newest read's bytes arrived; 0: unknown
        self.frames: deque[tuple[bytes, bool]] = deque()  # (frame, is a SIF), oldest first
        self.queued = 0  # bytes in frames
        self.head_sent = 0  # bytes of frames[0] already written (it can no longer be dropped)
        self.dropped = 0  # SIFs dropped because the host did not read
        os.set_blocking(fd, False)

    @property
    def pending(self) -> bool:
        return bool(self.frames)

    def recv(self) -> bytes | None:
        """Bytes, b"" if none now, None when the host went away."""
        self.arrived_age_ns = 0
        try:
            if self.kernel_stamps:
                assert self.sock is not None
                data, stamp = recv_stamped(self.sock, 4096)
                if stamp:
                    self.arrived_age_ns = time.clock_gettime_ns(time.CLOCK_REALTIME) - stamp
            else:
                data = self.sock.recv(4096) if self.sock else os.read(self.fd, 4096)
        except BlockingIOError:
            return b""
        except OSError as e:
            if e.errno == errno.EIO and self.sock is None:
                return b""  # pty with no host attached right now
            return None
        return data if data or self.sock is None else None

    def send(self, replies: bytes, sifs: list[bytes]) -> bool:
        if replies:
            self.frames.append((replies, False))
            self.queued += len(replies)
        for frame in sifs:
            self.frames.append((frame, True))
            self.queued += len(frame)
        if self.queued > OUT_LIMIT:
            self._shed()
        while self.frames:
            # One write for as many whole frames as fit (a syscall per frame would cost more).
            parts = [self.frames[0][0][self.head_sent :]]
            size = len(parts[0])
            for frame, _ in itertools.islice(self.frames, 1, None):
                if size >= _WRITE_CHUNK:
                    break
                parts.append(frame)
                size += len(frame)
            data = b"".join(parts)
            try:
                n = self.sock.send(data) if self.sock else os.write(self.fd, data)
            except BlockingIOError:
                return True
            except OSError:
                return False
            self.head_sent += n
            while self.frames and self.head_sent >= len(self.frames[0][0]):
                done = len(self.frames.popleft()[0])
                self.head_sent -= done
                self.queued -= done
            if n < len(data):
                return True
        return True

    def _shed(self) -> None:
        keep: deque[tuple[bytes, bool]] = deque()
        for i, (frame, is_sif) in enumerate(self.frames):
            if self.queued > OUT_LIMIT and is_sif and not (i == 0 and self.head_sent):
                self.queued -= len(frame)
                self.dropped += 1
            else:
                keep.append((frame, is_sif))
        self.frames = keep

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close()


class _Dialer:
    """The connection a dialing board makes (board/dial.py's DialServer over SocketNet): a new
    socket once it is up, ``ended()`` when it went (the next dial after the backoff)."""

    def __init__(self, url: str) -> None:
        host, port = dial_address(url)
        self.net = SocketNet()
        self.dial = DialServer(self.net, host, port, lambda: time.monotonic_ns() // 10**6)
        self._n: int | None = None

    def poll(self) -> socket.socket | None:
        n = self.dial.accept()
        if n is None:
            return None
        self._n = n
        sock: socket.socket | None = self.net.take(n)  # (its I/O is the server's from now)
        if sock is not None:
            sock.setblocking(False)
        return sock

    def ended(self) -> None:
        if self._n is not None:
            self.dial.drop(self._n)
            self._n = None


class BoardServer:
    """Runs ``runtime`` behind ``listen_url`` until ``stop()``; ``url`` is what hosts open.
    ``dial=True``: connects out to ``listen_url`` (a daemon's ``--listen``) instead."""

    def __init__(
        self,
        runtime: BoardRuntime,
        listen_url: str,
        *,
        resets: list[tuple[int, int]] | None = None,
        rebuild: Callable[[], BoardRuntime] | None = None,
        dial: bool = False,
    ) -> None:
        """``resets``: (CLOCK_MONOTONIC ns, boot gap ns) at which the board resets without
        dropping the link (a watchdog behind a UART bridge): output in flight is lost, input
        during the gap is ignored, then ``rebuild()`` is the freshly booted runtime (new epoch,
        SIF seq from 0; its clock restarts on its own, see DriftClock)."""
        self.runtime = runtime
        self.listen_url = listen_url
        self._resets = sorted(resets or [])
        self._rebuild = rebuild
        self._booting_until: int | None = None
        self.boots = 0
        self._stop = threading.Event()
        self._listener: socket.socket | None = None
        self._memory: MemoryListener | None = None
        self._link: _Link | None = None
        self._mem_link: MemoryTransport | None = None
        self._pty_slave: int | None = None
        self.connections = 0
        self._accept_failures = AcceptFailures()
        self._listen_after = 0.0  # (time.monotonic) the listener rests until then
        self._handover_waits = 0  # passes a newcomer has waited behind the last host's bytes
        self._dialer = _Dialer(listen_url) if dial else None
        self.url = f"dial {listen_url}" if dial else self._bind(listen_url)

    @property
    def accept_errors(self) -> int:
        """Accepts that failed (out of descriptors: EMFILE, ...)."""
        return self._accept_failures.count

    def _bind(self, url: str) -> str:
        if url == "pty" or url == "pty://":
            master, slave = os.openpty()
            # Raw mode at once: a cooked pty would echo the board's own frames back to it.
            tty.setraw(slave)
            tty.setraw(master)
            self._pty_slave = slave  # kept open so the master never sees EOF between hosts
            self._link = _Link(master)
            return f"serial://{os.ttyname(slave)}"
        if url.split("://", 1)[0] == "memory":
            self._memory = MemoryListener(urlsplit(url).netloc)
            return self._memory.url
        # tcp or unix (BadURL for anything else, saying what is taken)
        self._listener, bound = listen_socket(url, 1, "pty", "memory://NAME")
        return bound

    # ---- the process loop ---------------------------------------------------------------------
    def _wait_time(self) -> float:
        rt = self.runtime
        due = rt.next_deadline_us()
        wait: float = _MAX_WAIT if due is None else (due - rt.clock()) / 1e6
        events = [t for t in (self._booting_until, *(r for r, _g in self._resets[:1])) if t]
        if events:
            wait = min(wait, (min(events) - time.monotonic_ns()) / 1e9)
        return min(_MAX_WAIT, max(0.0, wait))

    def _lifecycle(self) -> bool:
        """Run scheduled resets; True while the board is booting (deaf and mute)."""
        now = time.monotonic_ns()
        if self._resets and now >= self._resets[0][0]:
            at, gap = self._resets.pop(0)
            self._booting_until = at + gap
            if self._link is not None:  # what the UART had not sent yet is gone
                self._link.frames.clear()
                self._link.queued = self._link.head_sent = 0
        if self._booting_until is not None:
            if now < self._booting_until:
                return True
            self._booting_until = None
            if self._rebuild is not None:
                self.runtime = self._rebuild()
            self.boots += 1
        return False

    def _turn(self, data: bytes, rx_us: int | None = None) -> tuple[bytes, list[bytes]]:
        """One turn of the board's process loop: feed input, run drivers, return output as
        (replies, SIF frames).  An exception stops the board, as it stops the firmware
        (board/firmware.py): every armed actuator made safe first."""
        try:
            if data:
                self.runtime.feed(data, rx_us)
            self.runtime.poll()
        except BaseException as e:
            if self.runtime.failsafe is not None:
                self.runtime.failsafe.stop(f"the firmware stops: {e}")
            raise
        out: tuple[bytes, list[bytes]] = self.runtime.take_frames()
        return out

    def serve_forever(self) -> None:
        if self._memory is not None:
            self._serve_memory()
            return
        try:
            while not self._stop.is_set():
                self.serve_once()
        finally:
            self.close()

    def serve_once(self) -> None:
        """One pass of the process loop: wait (at most ``_MAX_WAIT``) for input, a host or the
        next driver deadline; read; run a turn; write; then take a host that connected."""
        fds = []
        if self._link is not None:
            fds.append(self._link.fd)
        lfd = self._listener.fileno() if self._listener is not None else -1
        listening = lfd >= 0 and time.monotonic() >= self._listen_after  # (not while it rests)
        if listening:
            fds.append(lfd)
        wfds = [self._link.fd] if self._link is not None and self._link.pending else []
        ready, _, _ = select.select(fds, wfds, [], self._wait_time())
        rx_us = self.runtime.clock()  # input (if any) arrived before select returned
        data = b""
        if self._link is not None and self._link.fd in ready:
            received = self._link.recv()
            if received is None:
                self._drop_link()
            else:
                data = received
                age = self._link.arrived_age_ns
                if 0 < age < 1_000_000_000:  # the kernel's stamp, as a board clock reading
                    rx_us = self.runtime.clock() - age // 1000
        newcomer = listening and lfd in ready
        gone = False
        if newcomer and self._link is not None:
            rest, newcomer, gone = self._handover()
            data += rest
        if self._dialer is not None and self._link is None:
            sock = self._dialer.poll()  # (select wakes within _MAX_WAIT: dial steps)
            if sock is not None:
                self._link = _Link(sock.fileno(), sock)
                self.connections += 1
        if not self._lifecycle():  # (booting: input is lost, nothing is sent)
            replies, sifs = self._turn(data, rx_us)
            if self._link is not None and not self._link.send(replies, sifs):
                self._drop_link()
        if gone:  # (after its answer: a host that shut only its side still reads it)
            self._drop_link()
        if newcomer:
            # (after the turn: what the last host's last bytes are answered is not the new one's)
            self._accept()

    def _handover(self) -> tuple[bytes, bool, bool]:
        """A host connects while the link is up: the last host may have sent its last frame and
        closed in the same moment, its close still unread behind the frame.  Read what it left
        (the turn answers it on its own link, which a host that shut only its sending side still
        reads): its close ends the link after the turn and the newcomer is the next host;
        nothing more (it is still there) and the newcomer is a second host, turned away.
        Returns (bytes read, take the newcomer this turn, the last host closed); past
        ``_HANDOVER_READ`` bytes the last host is still sending: the newcomer waits in the
        backlog for the next turn, ``_HANDOVER_PASSES`` at most (then it is a second host)."""
        assert self._link is not None
        parts: list[bytes] = []
        size = 0
        while size < _HANDOVER_READ:
            got = self._link.recv()
            if got is None:  # it went: the link ends after the turn
                return b"".join(parts), True, True
            if not got:  # still there: _accept() turns the newcomer away
                return b"".join(parts), True, False
            parts.append(got)
            size += len(got)
        self._handover_waits += 1  # (reset as it is taken: _accept)
        return b"".join(parts), self._handover_waits >= _HANDOVER_PASSES, False

    def _accept(self) -> None:
        assert self._listener is not None
        self._handover_waits = 0
        try:
            sock, _ = self._listener.accept()
        except OSError as e:  # (the connection stays in the backlog: the listener rests)
            self._listen_after = time.monotonic() + self._accept_failures.failed(self.url, e)
            return
        self._accept_failures.taken()
        if self._link is not None:
            sock.close()  # one host at a time
            return
        self._link = _Link(sock.fileno(), sock)  # (TCP_NODELAY and kernel receive stamps)
        self.connections += 1

    def _drop_link(self) -> None:
        if self._link is not None and self._link.sock is not None:
            self._link.close()
            self._link = None
            # a frame the host cut is not the next host's to end (its error goes to nobody)
            self.runtime.parser.abort()
            if self._dialer is not None:
                self._dialer.ended()

    def _serve_memory(self) -> None:
        assert self._memory is not None
        link: MemoryTransport | None = None
        try:
            while not self._stop.is_set():
                if link is None:
                    link = self._memory.accept(self._wait_time())
                    if link is not None:
                        self.connections += 1
                    data = b""
                else:
                    try:
                        data = link.read(self._wait_time())
                    except (TransportBroken, TransportClosed):  # host went away: accept the next
                        link = None
                        data = b""
                replies, sifs = self._turn(data)
                out = replies + b"".join(sifs)
                if link is not None and out:
                    try:
                        link.write(out)
                    except (TransportBroken, TransportClosed):
                        link = None
        finally:
            if link is not None:
                link.close()
            self.close()

    @property
    def stopping(self) -> bool:
        """``stop()`` was called (a server that ends otherwise ended by itself)."""
        return self._stop.is_set()

    def stop(self) -> None:
        self._stop.set()

    def close(self) -> None:
        self._stop.set()
        if self._listener is not None:
            self._accept_failures.said_at_stop(self.url)
        if self._listener is not None:
            if self._listener.family == socket.AF_UNIX:
                try:
                    os.unlink(self._listener.getsockname())
                except OSError:
                    pass
            self._listener.close()
            self._listener = None
        if self._link is not None:
            if self._link.sock is None:
                os.close(self._link.fd)
            else:
                self._link.close()
            self._link = None
        if self._pty_slave is not None:
            os.close(self._pty_slave)
            self._pty_slave = None
        if self._memory is not None:
            self._memory.close()


def start_board_thread(
    runtime: BoardRuntime, listen_url: str = "tcp://127.0.0.1:0"
) -> tuple[BoardServer, threading.Thread]:
    """Run a virtual board in a background thread (tests, embedding).  Stop with server.stop()."""
    server = BoardServer(runtime, listen_url)
    thread = threading.Thread(target=server.serve_forever, name=f"board:{server.url}", daemon=True)
    thread.start()
    return server, thread
