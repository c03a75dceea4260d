"""Test helpers, each written once: waiting for a condition (``wait_for``), the command line
(``ML``, ``ml``), board processes (``board_process``), the MicroPython and AVR firmware in their
simulators (``FirmwareSim``, ``AvrSim``), a pipe transport to a board in a child process, thread
checks."""

from __future__ import annotations

import ast
import itertools
import json
import queue
import shutil
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from missing_link.errors import TransportBroken, TransportClosed
from missing_link.transport import Transport


class HexLinePipe(Transport):
    """A board in a child process that reads hex lines (bytes from the host) on stdin and answers
    each with one hex line (its output).  Used for the MicroPython board under node."""

    def __init__(self, cmd: list[str], ready_prefix: str = "READY", timeout: float = 60.0) -> None:
        self.url = "pipe:" + " ".join(cmd[:2])
        self.proc = subprocess.Popen(
            cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        self._lines: queue.Queue[str | None] = queue.Queue()
        self._closed = False
        pump_lines(self.proc, self._lines)
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
            assert self.proc.stdin is not None
            self.proc.stdin.close()  # (node's readline holds the loop open while stdin is)
        except (BrokenPipeError, OSError, ValueError):
            pass
        try:
            self.proc.wait(5)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(5)
        self._lines.put(None)


def pump_lines(proc: subprocess.Popen[str], into: queue.Queue[str | None]) -> None:
    """Start a thread that puts each stdout line of ``proc`` into ``into`` (None at EOF)."""

    def run() -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            into.put(line.rstrip("\n"))
        into.put(None)

    threading.Thread(target=run, daemon=True).start()


def wait_for(pred: Callable[[], object], timeout: float = 10.0, step: float = 0.02) -> bool:
    """Poll ``pred`` every ``step`` s until it is true or ``timeout`` s passed; a last look
    after that (tests only: the timeout is a bound on a hang, never a threshold)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(step)
    return bool(pred())


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


_SIM_SEEDS = itertools.count(1000)


class FirmwareSim:
    """The MicroPython firmware from a board file, under the real MicroPython interpreter (node,
    WebAssembly port) with simulated peripherals (src/missing_link/virtual/world), its J2A link on a
    TCP port.  ``ctl(code)`` runs Python against the simulated world and returns ``result``."""

    ROOT = Path(__file__).resolve().parent.parent
    HOST = ROOT / "src" / "missing_link" / "virtual" / "world" / "host.mjs"

    def __init__(
        self,
        board_file: Path | str,
        files: dict[str, Path] | None = None,
        args: list[str] | None = None,
    ) -> None:
        """``files``: put on the board's filesystem (name -> local file), as flash would;
        ``args``: more of host.mjs's (``--seed N``, ``--lib DIR``, ``--dial HOST:PORT``)."""
        if shutil.which("node") is None:
            raise RuntimeError("node is required: run `make node`")
        extra = [x for name, path in (files or {}).items() for x in ("--file", f"{name}={path}")]
        extra += args or []
        if "--seed" not in extra:  # (each simulated chip its own machine.unique_id(): board.id)
            extra += ["--seed", str(next(_SIM_SEEDS))]
        self.proc = subprocess.Popen(
            ["node", str(self.HOST), str(board_file), *extra],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            cwd=self.ROOT,
        )
        self._lines: queue.Queue[str | None] = queue.Queue()
        pump_lines(self.proc, self._lines)
        first = self._lines.get(timeout=60)
        if first is None or not first.startswith("LISTEN "):
            err = self.proc.stderr.read() if self.proc.stderr else ""
            raise RuntimeError(f"firmware simulator did not start: {first!r} {err[-2000:]}")
        _, port, self.ident = first.split(" ", 2)
        self.url = f"tcp://127.0.0.1:{port}"
        self._lock = threading.Lock()

    def ctl(self, code: str, timeout: float = 10.0) -> Any:
        """Run ``code`` in the simulator (WORLD, fw, rt, machine in scope); ``result`` comes
        back through ast.literal_eval (repr of plain values)."""
        assert self.proc.stdin is not None
        with self._lock:
            self.proc.stdin.write(json.dumps(code) + "\n")
            self.proc.stdin.flush()
            line = self._lines.get(timeout=timeout)
        if line is None or not line.startswith("OK "):
            raise RuntimeError(f"simulator: {line!r}")
        text = line[3:]
        return float("nan") if text == "nan" else ast.literal_eval(text)

    def next_line(self, timeout: float = 10.0) -> str | None:
        return self._lines.get(timeout=timeout)

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait(5)
        for f in (self.proc.stdin, self.proc.stdout, self.proc.stderr):
            if f is not None:
                f.close()


class AvrSim:
    """rig_sim running an ELF; ``ctl(line)`` talks to the simulated rig."""

    def __init__(
        self,
        build: Path,
        elf: Path,
        skew_ppm: float = 0.0,
        eeprom: Path | None = None,
        rover: bool = False,
        mcu: str | None = None,
        parts: Sequence[str] = (),
    ) -> None:
        """``eeprom``: the EEPROM's contents across power cycles (a file rig_sim reads at
        power-up and writes at power-off); ``rover``: a Mega with the rover's parts
        (firmware/avr/sim/rover.c); ``mcu``: another part than the Uno's (atmega2560);
        ``parts``: rig_sim's --part specs (the thesis rig's without)."""
        self.elf = elf
        extra = ["--eeprom", str(eeprom)] if eeprom is not None else []
        if rover:
            extra += ["--mcu", "atmega2560", "--rover"]
        elif mcu is not None:
            extra += ["--mcu", mcu]
        for spec in parts:
            extra += ["--part", spec]
        self.proc = subprocess.Popen(
            [str(build / "rig_sim"), str(elf), "--skew-ppm", str(skew_ppm), *extra],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        self.lines: queue.Queue[str | None] = queue.Queue()
        pump_lines(self.proc, self.lines)
        while True:
            line = self.lines.get(timeout=20)
            if line is None:
                raise RuntimeError(
                    f"rig_sim ended: {self.proc.stderr.read() if self.proc.stderr else ''}"
                )
            if line.startswith("PTY "):
                self.url = "serial://" + line.split()[1]
                break

    def power_off(self) -> None:
        """Quit the rig as a power-off: its EEPROM is written to the --eeprom file."""
        if self.proc.poll() is None:
            assert self.proc.stdin is not None
            self.proc.stdin.write("quit\n")
            self.proc.stdin.flush()
            self.proc.wait(10)
        self.close()

    def ctl(self, line: str) -> str:
        assert self.proc.stdin is not None
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()
        line = self.lines.get(timeout=10)
        if line is None:
            raise RuntimeError("rig_sim ended")
        return line

    def close(self) -> None:
        self.proc.kill()
        self.proc.wait(5)
        for f in (self.proc.stdin, self.proc.stdout, self.proc.stderr):
            if f is not None:
                f.close()


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
def board_process(*args: str) -> Iterator[str]:
    """``missing-link board ARGS`` on a free TCP port in a process of its own; yields its URL."""
    p = subprocess.Popen(
        [*ML, "board", "--listen", "tcp://127.0.0.1:0", *args],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert p.stdout is not None
        line = p.stdout.readline()
        assert line.startswith("LISTENING "), line
        yield line.split()[1]
    finally:
        p.terminate()
        p.wait(10)
