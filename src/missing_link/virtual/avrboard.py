"""An AVR board file's firmware in simavr as a virtual board (``board --file F --runtime avr``):
real AVR machine code in its rig (firmware/avr/sim/rig_sim.c, built and wired by
deploy/avrsim.py), its UART served on ``--listen``.

Theory of operation
-------------------
:class:`AvrBoard` starts rig_sim and waits for its ``PTY /dev/pts/N`` line: the board's UART is
then on that pseudo-terminal.  With ``--listen pty`` that is the board's URL, as a USB board's
port is.  With ``tcp://`` or ``unix://`` this process listens and relays one connection at a
time to the pty, as a serial server in front of a board: a second host waits until the first
leaves; what the board says while no host is connected goes nowhere (the pty's far end is read
and dropped, as a UART with nothing on its line).  rig_sim's stdin is the rig's control channel
(:meth:`ctl`: one line in, one line out; rig.h: the parts' state, the seam a world drives);
a world's ``tick`` line (:meth:`ctl_post`) is answered at the tick's simulated time, its answer
handed to :attr:`on_tick` in the thread that reads the rig, not queued with the others;
closing it powers the board off, its EEPROM saved to ``--eeprom`` (``board --flash DIR``).  The
rig ending on its own means the AVR stopped: serve_forever() raises :class:`FirmwareStopped`.
"""

from __future__ import annotations

import logging
import os
import queue
import select
import socket
import subprocess
import threading
import time
import tty
from collections.abc import Callable

from ..errors import MissingLinkError
from .boardfile import listener
from .listen import AcceptFailures
from .process import hang_up, reap

log = logging.getLogger(__name__)

START_TIMEOUT_S = 30.0


class FirmwareStopped(MissingLinkError):
    """The AVR in simavr stopped (rig_sim ended: a crash, or it could not start)."""


class AvrBoard:
    """rig_sim running ``command`` (deploy/avrsim.SimBuild.command), served on ``listen``
    (``pty``, ``tcp://HOST:PORT``, ``unix:///PATH``)."""

    def __init__(self, command: list[str], listen: str) -> None:
        self._server: socket.socket | None = None
        self.accept_failures = AcceptFailures()
        self._wake_r = self._wake_w = -1
        # (a session of its own: a terminal's Ctrl-C is this process's to handle)
        self.proc = subprocess.Popen(
            command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
            text=True, start_new_session=True,
        )  # fmt: skip
        self.lines: queue.Queue[str | None] = queue.Queue()
        #: where the rig's answers to ctl_post's ``tick`` lines go (world_avr.py), in the
        #: thread that reads the rig: it must not block on ctl_lines, nor raise
        self.on_tick: Callable[[str], None] | None = None
        threading.Thread(target=self._pump, name="board:rig", daemon=True).start()
        first: str | None = ""
        deadline = time.monotonic() + START_TIMEOUT_S
        while first is not None and not first.startswith("PTY "):  # (simavr says what it loaded)
            try:
                first = self.lines.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                first = None
        if first is None:
            self.close()
            err = self.proc.stderr.read().strip() if self.proc.stderr else ""
            raise FirmwareStopped(f"the firmware did not start in simavr: {err or 'no pty'}")
        self.pty = first.split()[1]
        self._lock = threading.Lock()  # (ctl_lines: a caller's lines and its answers)
        self._write = threading.Lock()  # (a write: ctl_post takes this one alone)
        self._wake_r, self._wake_w = os.pipe()
        if listen in ("pty", "pty://"):
            self.url = f"serial://{self.pty}"
        else:
            try:
                self._server, self.url = listener(listen)
            except MissingLinkError:
                self.close()
                raise

    def _pump(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            on_tick = self.on_tick
            if on_tick is not None and line.startswith(("tick ", "error tick")):
                # (the world's answer to its own line, its refusal "error tick: ..." too: never
                # one for ctl's queue, which would then answer each caller the line before)
                try:
                    on_tick(line.rstrip("\n"))
                except Exception:  # (this thread must go on reading the rig)
                    log.exception("rig: the world's tick failed")
            else:
                self.lines.put(line.rstrip("\n"))
        self.lines.put(None)

    def ctl(self, line: str, timeout: float = 10.0) -> str:
        """One line to the rig's control channel, its answer (rig.h: the parts' lines)."""
        return self.ctl_lines([line], timeout)[0]

    def ctl_lines(self, lines: list[str], timeout: float = 10.0) -> list[str]:
        """Lines to the rig's control channel at once, their answers in order: one round trip
        (the rig takes every line it has between two runs of the AVR)."""
        assert self.proc.stdin is not None
        with self._lock:
            self._put(lines)
            got: list[str] = []
            while len(got) < len(lines):
                answer = self.lines.get(timeout=timeout)
                if answer is None:
                    raise FirmwareStopped("the rig ended")
                got.append(answer)
        return got

    def ctl_post(self, line: str) -> None:
        """A ``tick`` line (rig_sim.c), its answer not waited for: it comes at the tick's
        simulated time, to :attr:`on_tick`."""
        self._put([line])

    def _put(self, lines: list[str]) -> None:
        assert self.proc.stdin is not None
        with self._write:
            self.proc.stdin.write("".join(line + "\n" for line in lines))
            self.proc.stdin.flush()

    def serve_forever(self) -> None:
        """Until stop() (returns) or the AVR stops (FirmwareStopped)."""
        try:
            if self._server is None:  # (the pty is the hosts' own)
                while self.proc.poll() is None:
                    if select.select([self._wake_r], [], [], 0.5)[0]:
                        return
            else:
                pty = os.open(self.pty, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
                try:
                    tty.setraw(pty)
                    if self._serve(self._server, pty):
                        return
                finally:
                    os.close(pty)
            raise FirmwareStopped(
                f"the AVR in simavr stopped (rig_sim exit {self.proc.returncode})"
            )
        finally:
            self.close()

    def _serve(self, server: socket.socket, pty: int) -> bool:
        """One host at a time until stop() (True) or the rig ends (False)."""
        while self.proc.poll() is None:
            ready = select.select([self._wake_r, pty, server.fileno()], [], [], 0.5)[0]
            if self._wake_r in ready:
                return True
            if pty in ready:
                _drain(pty)  # (no host: what the board says goes nowhere)
            if server.fileno() in ready:
                try:
                    conn, _ = server.accept()
                except OSError as e:  # (out of descriptors: the connection waits in the backlog)
                    pause = self.accept_failures.failed(self.url, e)
                    if select.select([self._wake_r], [], [], pause)[0]:
                        return True  # (stop() meanwhile)
                    continue
                self.accept_failures.taken()
                with conn:
                    if self._relay(conn, pty):
                        return True
        return False

    def _relay(self, conn: socket.socket, pty: int) -> bool:
        """Bytes both ways until the host leaves (False) or stop() (True)."""
        conn.setblocking(False)
        while self.proc.poll() is None:
            ready = select.select([conn.fileno(), pty, self._wake_r], [], [], 0.5)[0]
            if self._wake_r in ready:
                return True
            try:
                if conn.fileno() in ready:
                    data = conn.recv(4096)
                    if not data:
                        return False
                    _write_all(pty, data)
                if pty in ready:
                    data = _drain(pty)
                    if data:
                        conn.sendall(data)
            except (BlockingIOError, ConnectionError):
                return False
        return False

    def stop(self) -> None:
        """Power off: the relay ends, rig_sim's stdin closes (its EEPROM is saved)."""
        if self._wake_w >= 0:
            os.write(self._wake_w, b"x")

    def close(self) -> None:
        hang_up(self.proc)
        reap(self.proc)
        if self._server is not None:
            self.accept_failures.said_at_stop(self.url)
            self._server.close()
            self._server = None
        for fd in ("_wake_r", "_wake_w"):
            if getattr(self, fd, -1) >= 0:
                os.close(getattr(self, fd))
                setattr(self, fd, -1)


def _drain(fd: int) -> bytes:
    try:
        return os.read(fd, 4096)
    except (BlockingIOError, OSError):
        return b""


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        try:
            view = view[os.write(fd, view) :]
        except BlockingIOError:
            select.select([], [fd], [], 0.5)
