"""Test helpers, each written once: the command line (``ML``, ``ml``), board processes
(``board_process``), a pipe transport to a board in a child process, thread checks, a periodic
transducer's interval from its stamps (``period_seen_us``); waiting for
a condition (``wait_for``) and the MicroPython and AVR firmware in their simulators
(``FirmwareSim``, ``AvrSim``) are the library's (missing_link.testing)."""

from __future__ import annotations

import json
import queue
import socket
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config
from missing_link.errors import TransportBroken, TransportClosed
from missing_link.testing import AvrSim as AvrSim
from missing_link.testing import MicroPythonSim
from missing_link.testing import wait_for as wait_for
from missing_link.testing.sims import start_with_lines as start_with_lines
from missing_link.transport import Transport
from missing_link.virtual.mpyboard import HOST_MJS, find_micropython
from missing_link.virtual.process import hang_up, reap


class HexLinePipe(Transport):
    """A board in a child process that reads hex lines (bytes from the host) on stdin and answers
    each with one hex line (its output).  Used for the MicroPython board under node."""

    def __init__(self, cmd: list[str], ready_prefix: str = "READY", timeout: float = 60.0) -> None:
        self.url = "pipe:" + " ".join(cmd[:2])
        self.proc, self._lines = start_with_lines(cmd)
        self._closed = False
        first = self._lines.get(timeout=timeout)
        if first is None or not first.startswith(ready_prefix):
            err = self.proc.stderr.read() if self.proc.stderr else ""
            raise RuntimeError(f"board process did not start: {first!r} {err}")
        self.ident = first[len(ready_prefix) :].strip()
        self._lock = threading.Lock()

    def send_line(self, line: str) -> None:
        assert self.proc.stdin is not None
        with self._lock:
            self.proc.stdin.write(line + "\n")
            self.proc.stdin.flush()

    def command(self, line: str, timeout: float = 10.0) -> str:
        """A line of the setup's own (REBOOT, CUT n, ...): its answer line as it is."""
        self.send_line(line)
        answer = self._lines.get(timeout=timeout)
        assert answer is not None, f"{self.url}: board process ended"
        return answer

    def exchange(self, data: bytes, timeout: float = 10.0) -> bytes:
        """Raw use without a reader thread: send bytes, return the board's output."""
        self.send_line(data.hex())
        return self.read(timeout)

    def read(self, timeout: float | None) -> bytes:
        if self._closed:
            raise TransportClosed(f"{self.url}: closed")
        try:
            line = self._lines.get(timeout=timeout)
        except queue.Empty:
            return b""
        if line is None:
            if self._closed:
                raise TransportClosed(f"{self.url}: closed")
            raise TransportBroken(f"{self.url}: board process ended")
        if line.startswith("ERROR"):
            raise TransportBroken(f"{self.url}: {line}")
        return bytes.fromhex(line)

    def write(self, data: bytes) -> None:
        if self._closed:
            raise TransportClosed(f"{self.url}: closed")
        self.send_line(data.hex())

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            self.send_line("QUIT")
        except (BrokenPipeError, OSError, ValueError):
            pass
        hang_up(self.proc)  # (node's readline holds the loop open while stdin is)
        reap(self.proc)
        self._lines.put(None)


#: the command line as a user runs it, from this checkout with this Python
ML = [sys.executable, "-m", "missing_link"]


def ml(*args: str, timeout: float = 120, **kw: Any) -> subprocess.CompletedProcess[str]:
    """``missing-link ARGS`` to its end, in a process of its own; output captured as text
    (``kw``: more for subprocess.run, e.g. ``env``, ``input``)."""
    return subprocess.run([*ML, *args], capture_output=True, text=True, timeout=timeout, **kw)


def j2a_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name.startswith(("j2a:", "board:"))]


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago (for servers a test starts)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class FirmwareSim(MicroPythonSim):
    """The MicroPython firmware of a board file under node: the library's (missing_link.testing),
    by the name the tests knew it by, with the checkout's places (the simulator's host.mjs)."""

    ROOT = Path(__file__).resolve().parent.parent
    HOST = HOST_MJS


#: the ``avr_rig`` fixture (conftest.py): avr_rig(firmware, skew_ppm=, eeprom=, rover=) -> AvrSim
AvrRig = Callable[..., AvrSim]


def read_blob_raw(exchange: Callable[[bytes], bytes], target: int, size: int) -> bytes:
    """Read a many-function's blob chunk by chunk with raw a2jMany requests (``exchange``:
    request bytes in, the board's output out), checking each reply echoes its offset and only
    the last says isLast: what our runtimes serve past offset 255, where the 2014 firmware used
    only the offset's low byte (a host meeting a Part 1 board stops there, not knowing which)."""
    from missing_link.j2a import SOF, Frame, FrameDecoder, FrameKind, encode_frame
    from missing_link.j2a.blobs import many_request

    blob = b""
    for k, offset in enumerate(range(0, size, 249)):
        out = exchange(encode_frame(SOF, (20 + k) & 0xFF, 1, many_request(target, 0, offset)))
        (frame,) = [
            f for f in FrameDecoder().feed(out) if isinstance(f, Frame) and f.kind == FrameKind.SOF
        ]
        payload = frame.payload
        assert frame.opcode == 0 and payload[2:6] == offset.to_bytes(4, "little"), payload[:6]
        assert bool(payload[1] & 1) == (offset + 249 >= size)
        blob += payload[6:]
    return blob


@contextmanager
def daemon_up(url: str, **spec: Any) -> Iterator[Daemon]:
    """A daemon in this process on the board at ``url`` (a BoardSpec: timeout 2 s unless
    ``spec`` says), up within 30 s (a bound on a hang: its failures in the message)."""
    with Daemon(Config(boards=[BoardSpec(url, **{"timeout": 2.0, **spec})])) as d:
        assert d.wait_until_up(30), d.failures()
        yield d


@contextmanager
def board_process(*args: str, cmd: list[str] = ML, cwd: Path | None = None) -> Iterator[str]:
    """``missing-link board ARGS`` on a free TCP port in a process of its own; yields its URL
    (``cmd``: another ``missing-link``, e.g. an installed one, run in ``cwd``)."""
    p = subprocess.Popen(
        [*cmd, "board", "--listen", "tcp://127.0.0.1:0", *args],
        stdout=subprocess.PIPE,
        text=True,
        cwd=cwd,
    )
    try:
        assert p.stdout is not None
        line = p.stdout.readline()
        assert line.startswith("LISTENING "), line
        yield line.split()[1]
    finally:
        p.terminate()
        p.wait(10)


def simworld_probe(probe: str, cases: Any) -> list[dict[str, Any]]:
    """Run ``tests/micropython/<probe>.py`` against the MicroPython simulator's modules in real
    MicroPython (tests/micropython/simworld.mjs): its ``run(*case)`` for each case, the JSON
    line each printed."""
    node, _mpy = find_micropython()
    here = Path(__file__).resolve().parent
    out = subprocess.run(
        [node, str(here / "micropython" / "simworld.mjs"),
         str(here.parent / "src" / "missing_link" / "virtual" / "world"),
         str(here / "micropython" / f"{probe}.py"), json.dumps(cases)],
        capture_output=True, text=True, timeout=60, check=True, cwd=here.parent,
    ).stdout  # fmt: skip
    return [json.loads(line) for line in out.splitlines() if line.startswith("{")]


def period_seen_us(stamps: list[int], span: int = 10) -> float:
    """A periodic transducer's interval from its board stamps: the shortest time ``span``
    consecutive intervals took, per interval.  A Periodic (board/drivers) keeps its slots: a
    sample measured late (the loop was busy: the HC-SR04's echo wait blocks it up to 26 ms) is
    followed by one on its slot, so ``span`` intervals at period P take at least (span - 1) P
    less one hold of the loop (at 20 Hz beside the rover's sonar: over 42 ms an interval),
    however often it was held; and a stall (slots skipped) only lengthens the windows it is
    in, not the shortest.  Not the median interval: a driver that blocks every other slot makes
    the intervals alternate P + x, P - x, and their median is either (tests/test_periodic.py)."""
    if len(stamps) <= span:
        raise ValueError(f"{len(stamps)} stamps: at least {span + 1} needed")
    return min(b - a for a, b in zip(stamps, stamps[span:], strict=False)) / span
