"""Test helpers: a pipe transport to a board in a child process, thread checks."""

from __future__ import annotations

import queue
import socket
import subprocess
import threading

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
        threading.Thread(target=self._pump, daemon=True).start()
        first = self._lines.get(timeout=timeout)
        if first is None or not first.startswith(ready_prefix):
            err = self.proc.stderr.read() if self.proc.stderr else ""
            raise RuntimeError(f"board process did not start: {first!r} {err}")
        self.ident = first[len(ready_prefix) :].strip()
        self._lock = threading.Lock()

    def _pump(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self._lines.put(line.rstrip("\n"))
        self._lines.put(None)

    def send_line(self, line: str) -> None:
        assert self.proc.stdin is not None
        with self._lock:
            self.proc.stdin.write(line + "\n")
            self.proc.stdin.flush()

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
        try:
            self.proc.wait(5)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(5)
        self._lines.put(None)


def j2a_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name.startswith(("j2a:", "board:"))]


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago (for servers a test starts)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])
