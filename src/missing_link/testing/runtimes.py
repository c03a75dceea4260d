"""A board under test on any runtime, one interface: :class:`RuntimeBoard`.

Theory of operation
-------------------
A test says what it does to a board (a host that calls, configures and hangs up; bytes on the
line; board time passing) once, and runs on every runtime: our runtime on CPython, our firmware
under real MicroPython (node) and the AVR firmware in simavr (:mod:`.sims`).  Each runtime
board gives:

- ``host()``: the one host link, a handshaken :class:`~missing_link.host.board.Board`, opened
  on first use and kept until ``hang_up()`` (then the board hears nothing: the host has gone);
  ``call(name, payload)`` calls through it and gives the decoded :class:`Answer`;
- ``line()``: a raw byte line to the board as its host (a :class:`Transport`), for what no
  host would send;
- ``board_us()``: the board's own clock, read without a frame on its link (the simulator's
  control channel, or the clock a test turns), and ``run(us, each=...)`` / ``run_until(...)``:
  board time passing, ``each()`` called every turn (a host that keeps talking, noise on the
  line), on the board's clock, never a fixed sleep.

:class:`SteppedBoard` is a CPython virtual board in this process on a :class:`FakeBoardClock`:
nothing runs until the test turns the clock (a turn: 20 ms of board time, then the runtime's
poll), and what a host writes is fed at once, so a test of time (failsafe, keepalive, timed
calls) is exact and takes no real time.  :class:`ProcessBoard` is a board file on CPython in
a process of its own (its clock is this host's CLOCK_MONOTONIC).
"""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from abc import abstractmethod
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ..closing import Closing
from ..errors import TransportClosed
from ..host.board import Board
from ..transport import Transport, open_transport
from ..virtual.process import stop_process
from .board_clock import FakeBoardClock
from .calls import Answer

#: the runtimes a board runs on, in the order a test runs them
RUNTIMES = ("cpython", "micropython", "avr")
#: a turn of :meth:`RuntimeBoard.run`: the board time between two looks (or ``each()``)
TURN_US = 20_000
#: how long a board may take to pass the board time a test waits for (s of real time): a bound
#: on a hang, never what a test checks
HANG_S = 60.0


class RuntimeBoard(Closing):
    """A board under test (see the module's docstring).  ``runtime``: one of :data:`RUNTIMES`;
    ``url``: what a host opens (a ``SteppedBoard``'s is only its name)."""

    runtime: str = ""
    url: str = ""
    #: a host's timeout for a call (s)
    timeout = 5.0
    _host: Board | None = None

    # ---- the host --------------------------------------------------------------------------
    def line(self) -> Transport:
        """A new raw line to the board, as its host (close it to hang up)."""
        return open_transport(self.url)

    def host(self, describe: bool = True) -> Board:
        """The host link, handshaken (``describe``: with the transducers' descriptors)."""
        if self._host is None:
            board = Board(self.line(), timeout=self.timeout)
            try:
                board.handshake(describe=describe)
            except BaseException:
                board.close()
                raise
            self._host = board
        return self._host

    def call(self, name: str, payload: bytes = b"") -> Answer:
        """``name`` called through the host link: the board's answer, decoded."""
        r = self.host().call(name, payload, self.timeout)
        return Answer(r.code, r.payload)

    def hang_up(self) -> None:
        """Close the host link, if open: the host has gone (no goodbye)."""
        if self._host is not None:
            board, self._host = self._host, None
            board.close()

    # ---- time ------------------------------------------------------------------------------
    @abstractmethod
    def board_us(self) -> int:
        """The board's clock (µs), read without a frame on its link."""

    def turn(self) -> None:
        """Let a turn of board time pass (a real runtime: wait for it, bounded)."""
        end = self.board_us() + TURN_US
        deadline = time.monotonic() + HANG_S
        while self.board_us() < end:
            if time.monotonic() > deadline:
                raise AssertionError(f"{self}: its clock stood still for {HANG_S} s")
            time.sleep(TURN_US / 1e6 / 4)

    def run(self, us: int, each: Callable[[], object] | None = None) -> None:
        """Let ``us`` of board time pass, turn by turn, calling ``each()`` before every turn."""
        end = self.board_us() + us
        while self.board_us() < end:
            if each is not None:
                each()
            self.turn()

    def run_until(
        self, done: Callable[[], object], us: int, each: Callable[[], object] | None = None
    ) -> bool:
        """:meth:`run` until ``done()`` or ``us`` of board time passed; ``done()`` then."""
        end = self.board_us() + us
        while not done():
            if self.board_us() >= end:
                return bool(done())
            if each is not None:
                each()
            self.turn()
        return True

    def close(self) -> None:
        """Hang up and stop the board (its simulator, its process)."""
        self.hang_up()

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.runtime} {self.url}>"


class _SteppedLine(Transport):
    """The host's end of a line to a :class:`SteppedBoard`: what it writes is fed to the
    runtime at once (the replies come with it); the rest of the runtime's output comes as the
    test turns the board's clock."""

    wakes_on_close = True

    def __init__(self, board: SteppedBoard) -> None:
        self.url = board.url
        self._board = board
        self._out = bytearray()
        self._cond = threading.Condition(board.lock)
        self._closed = False

    def take(self) -> None:  # (the board's lock held)
        replies, sifs = self._board.rt.take_frames()
        self._out += replies + b"".join(sifs)
        if self._out:
            self._cond.notify_all()

    def write(self, data: bytes) -> None:
        with self._cond:
            if self._closed:
                raise TransportClosed(f"{self.url}: closed")
            self._board.rt.feed(bytes(data))
            self.take()

    def read(self, timeout: float | None) -> bytes:
        with self._cond:
            if not self._out and not self._closed:
                self._cond.wait(timeout)
            if self._closed:
                raise TransportClosed(f"{self.url}: closed")
            data = bytes(self._out)
            self._out.clear()
            return data

    def poke(self) -> None:
        with self._cond:
            self._cond.notify_all()

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()
            self._board.detach(self)


class SteppedBoard(RuntimeBoard):
    """A board runtime in this process (``make_sim``'s, or any ``BoardRuntime``) on a
    :class:`FakeBoardClock`: board time passes only in :meth:`turn` (20 ms, then one poll).
    ``rt``: the runtime, for what a test looks at inside it; one line at a time, as a UART
    (a new one takes the board; output with no line open is lost, as on a wire)."""

    runtime = "cpython"

    def __init__(self, rt: Any, clock: FakeBoardClock, name: str = "stepped") -> None:
        self.rt = rt
        self.clock = clock
        self.url = f"stepped://{name}"
        self.lock = threading.RLock()
        self._line: _SteppedLine | None = None

    def line(self) -> Transport:
        with self.lock:
            if self._line is not None:
                self._line.close()
            self._line = _SteppedLine(self)
            return self._line

    def detach(self, line: _SteppedLine) -> None:
        with self.lock:
            if self._line is line:
                self._line = None

    def board_us(self) -> int:
        return self.clock.us

    def turn(self) -> None:
        with self.lock:
            self.clock.advance(TURN_US)
            self.rt.poll()
            if self._line is not None:
                self._line.take()
            else:
                self.rt.take_frames()


class ProcessBoard(RuntimeBoard):
    """A board file on our CPython runtime, in a process of its own (``missing-link board
    --file``) on a TCP port of 127.0.0.1; its clock is this host's CLOCK_MONOTONIC (µs)."""

    runtime = "cpython"

    def __init__(self, board_file: Path | str, args: list[str] | None = None) -> None:
        cmd = [sys.executable, "-m", "missing_link", "board", "--file", str(board_file)]
        self.proc = subprocess.Popen(
            [*cmd, "--listen", "tcp://127.0.0.1:0", *(args or [])],
            stdout=subprocess.PIPE,
            text=True,
        )
        assert self.proc.stdout is not None
        first = self.proc.stdout.readline()
        if not first.startswith("LISTENING "):
            self.proc.kill()
            self.proc.wait(10)
            raise RuntimeError(f"{board_file}: the board did not start: {first!r}")
        self.url = first.split()[1]

    def board_us(self) -> int:
        return time.monotonic_ns() // 1000

    def close(self) -> None:
        super().close()
        stop_process(self.proc, grace=10)
        if self.proc.stdout is not None:
            self.proc.stdout.close()
