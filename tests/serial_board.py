"""A MicroPython board on a serial port, for tools that talk to boards (mpremote): a pty whose
other end is MicroPython's own REPL and filesystem (tests/micropython/serial_board.mjs, real
MicroPython 1.27 under node).  The board's flash is a host directory: it is loaded at power-on
and written back at a hard reset (``machine.reset()``: the board leaves the port, as a USB board
does when it resets) and at power-off (``close()``), so a test reads back what a tool wrote."""

from __future__ import annotations

import os
import select
import shutil
import subprocess
import threading
import tty
from pathlib import Path

from missing_link.virtual.process import hang_up, reap

ROOT = Path(__file__).resolve().parent.parent
DEVICE = ROOT / "tests" / "micropython" / "serial_board.mjs"


class SerialBoard:
    def __init__(self, flash: Path) -> None:
        if shutil.which("node") is None:
            raise RuntimeError("node is required: run `make node`")
        self.flash = flash
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # (a tool sets its own mode when it opens the port)
        self.port = os.ttyname(self._slave)
        os.set_blocking(self._master, False)
        self.proc = subprocess.Popen(
            ["node", str(DEVICE), str(flash)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            cwd=ROOT,
        )
        self.was_reset = False
        self._gone = threading.Event()
        self._closed = threading.Event()
        threading.Thread(target=self._to_board, daemon=True).start()
        threading.Thread(target=self._from_board, daemon=True).start()

    def _to_board(self) -> None:
        """RX: the port's bytes to the board, until the board is gone; then the port hangs up
        (whoever has it open reads and writes errors, as when a USB board resets)."""
        stdin = self.proc.stdin
        assert stdin is not None
        while not self._gone.is_set():
            if not select.select([self._master], [], [], 0.05)[0]:
                continue
            try:
                data = os.read(self._master, 4096)
                stdin.write(data)
                stdin.flush()
            except (OSError, ValueError):  # the board is going: its bytes are lost, as on a wire
                pass
        os.close(self._master)
        os.close(self._slave)
        self._closed.set()

    def _from_board(self) -> None:
        """TX: the board's bytes to the port, until the board's process ends."""
        stdout = self.proc.stdout
        assert stdout is not None
        while data := stdout.read1(4096):
            try:
                os.write(self._master, data)
            except OSError:  # (nobody reads the port: what does not fit is lost, as on a wire)
                pass
        self.proc.wait()
        assert self.proc.stderr is not None
        self.was_reset = b"RESET" in self.proc.stderr.read()
        self._gone.set()

    def wait_gone(self, timeout: float) -> bool:
        return self._gone.wait(timeout)

    def close(self) -> None:
        """Power off: the filesystem goes back to ``flash`` (if the board is still running)."""
        if self.proc.poll() is None:
            hang_up(self.proc)
        reap(self.proc, 20)
        self._closed.wait(5)
        for f in (self.proc.stdout, self.proc.stderr):
            if f is not None:
                f.close()
