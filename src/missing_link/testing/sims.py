"""Our firmware in its simulators, as boards under test (:class:`RuntimeBoard`): the MicroPython
firmware of a board file under the real MicroPython interpreter (node, WebAssembly port, with
the simulated world of ``virtual/world``: :class:`MicroPythonSim`) and the AVR firmware as AVR
machine code in simavr (``firmware/avr/sim``'s rig_sim: :class:`AvrSim`, built by
:func:`build_avr`).  Each has its simulator's control channel: ``ctl``."""

from __future__ import annotations

import ast
import fcntl
import hashlib
import itertools
import json
import queue
import shutil
import subprocess
import sys
import threading
from collections.abc import Sequence
from importlib import resources
from pathlib import Path
from typing import Any

from ..deploy.avr import AVR_DIR
from ..deploy.avrsim import rig_parts
from ..deploy.boardfile import load_board_file
from ..virtual.mpyboard import HOST_MJS, find_micropython
from .runtimes import RuntimeBoard

_SEEDS = itertools.count(1000)


def pump_lines(proc: subprocess.Popen[str], into: queue.Queue[str | None]) -> None:
    """Start a thread that puts each stdout line of ``proc`` into ``into`` (None at EOF)."""

    def run() -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            into.put(line.rstrip("\n"))
        into.put(None)

    threading.Thread(target=run, daemon=True).start()


def start_with_lines(
    cmd: list[str], cwd: Path | None = None, pass_fds: tuple[int, ...] = ()
) -> tuple[subprocess.Popen[str], queue.Queue[str | None]]:
    """Start ``cmd`` with its stdin, stdout and stderr piped (text) and ``pass_fds`` passed on;
    the child, and a queue of its stdout lines as they come (pump_lines)."""
    proc = subprocess.Popen(
        cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        cwd=cwd, pass_fds=pass_fds,
    )  # fmt: skip
    lines: queue.Queue[str | None] = queue.Queue()
    pump_lines(proc, lines)
    return proc, lines


def _end(proc: subprocess.Popen[str]) -> None:
    if proc.poll() is None:
        proc.kill()
    proc.wait(5)
    for f in (proc.stdin, proc.stdout, proc.stderr):
        if f is not None:
            f.close()


class MicroPythonSim(RuntimeBoard):
    """The MicroPython firmware of ``board_file`` under node (``virtual/world/host.mjs``), its
    J2A link on a TCP port of 127.0.0.1.  ``ctl(code)`` runs Python in the simulator (WORLD,
    fw, rt, machine in scope) and gives back ``result``; ``next_line()``: the simulator's next
    line of its own ("BREAK", "CRASH")."""

    runtime = "micropython"

    def __init__(
        self,
        board_file: Path | str,
        files: dict[str, Path] | None = None,
        args: list[str] | None = None,
    ) -> None:
        """``files``: put on the board's filesystem (name -> local file), as flash would;
        ``args``: more of host.mjs's (``--seed N``, ``--lib DIR``, ``--dial HOST:PORT``)."""
        node, entry = find_micropython()
        extra = [x for name, path in (files or {}).items() for x in ("--file", f"{name}={path}")]
        extra += args or []
        if "--seed" not in extra:  # (each simulated chip its own machine.unique_id(): board.id)
            extra += ["--seed", str(next(_SEEDS))]
        cmd = [node, str(HOST_MJS), str(board_file), "--mpy", str(entry), *extra]
        self.proc, self._lines = start_with_lines(cmd)
        first = self._lines.get(timeout=60)
        if first is None or not first.startswith("LISTEN "):
            err = self.proc.stderr.read() if self.proc.stderr else ""
            _end(self.proc)
            raise RuntimeError(f"firmware simulator did not start: {first!r} {err[-2000:]}")
        _, port, self.ident = first.split(" ", 2)
        self.url = f"tcp://127.0.0.1:{port}"
        self._lock = threading.Lock()

    def ctl(self, code: str, timeout: float = 10.0) -> Any:
        """Run ``code`` in the simulator; ``result`` comes back through ast.literal_eval (the
        repr of plain values)."""
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

    def board_us(self) -> int:
        return int(self.ctl("result = rt.clock()"))

    def close(self) -> None:
        super().close()
        _end(self.proc)


class AvrSim(RuntimeBoard):
    """rig_sim (``build``/rig_sim) running the AVR image ``elf``, its UART on a pseudo-terminal
    (``url``: serial://); ``ctl(line)`` talks to the simulated rig (firmware/avr/sim)."""

    runtime = "avr"

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
        power-up and writes at power-off); ``rover``: a Mega with the parts of the rover's
        board file (examples/boards/rover-mega.py, wired by deploy/avrsim.rig_parts); ``mcu``:
        another part than the Uno's (atmega2560); ``parts``: rig_sim's --part specs (the
        thesis rig's without)."""
        self.elf = elf
        extra = ["--eeprom", str(eeprom)] if eeprom is not None else []
        if rover:  # (the rig's parts at the rover's pins, as `board --runtime avr` wires them)
            examples = Path(str(resources.files("missing_link"))) / "examples" / "boards"
            rover_mega = examples / "rover-mega.py"
            extra += ["--mcu", "atmega2560"]
            parts = [*parts, *rig_parts(load_board_file(rover_mega))]
        elif mcu is not None:
            extra += ["--mcu", mcu]
        for spec in parts:
            extra += ["--part", spec]
        cmd = [str(build / "rig_sim"), str(elf), "--skew-ppm", str(skew_ppm), *extra]
        self.proc, self.lines = start_with_lines(cmd)
        while True:
            line = self.lines.get(timeout=20)
            if line is None:
                err = self.proc.stderr.read() if self.proc.stderr else ""
                _end(self.proc)
                raise RuntimeError(f"rig_sim ended: {err}")
            if line.startswith("PTY "):
                self.url = "serial://" + line.split()[1]
                break

    def ctl(self, line: str) -> str:
        assert self.proc.stdin is not None
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()
        answer = self.lines.get(timeout=10)
        if answer is None:
            raise RuntimeError("rig_sim ended")
        return answer

    def board_us(self) -> int:
        return int(self.ctl("stats").split()[2])  # simulated µs (the board's clock from reset)

    def power_off(self) -> None:
        """Quit the rig as a power-off: its EEPROM is written to the --eeprom file."""
        self.hang_up()
        if self.proc.poll() is None:
            assert self.proc.stdin is not None
            self.proc.stdin.write("quit\n")
            self.proc.stdin.flush()
            self.proc.wait(10)
        self.close()

    def close(self) -> None:
        super().close()
        _end(self.proc)


def build_avr(root: Path, boards: Sequence[tuple[Path, Sequence[str]]]) -> Path:
    """The AVR firmware of ``boards`` (board file, make targets: ``all``, ``sim`` for rig_sim,
    ``golden``), built by ``firmware/avr``'s Makefile into one directory below ``root``, named
    by what it is built from (the board files, the targets, the C sources): built once, by
    whichever process comes first (a lock file: pytest-xdist's workers share ``root``), and
    found built by the others.  The image of a board named N is ``DIR/N/firmware.elf``; what
    make said, ``DIR/build.log``."""
    for tool in ("avr-gcc", "cc", "make"):
        if shutil.which(tool) is None:
            raise RuntimeError(f"{tool} is required for the AVR firmware (scripts/system-deps.sh)")
    key = hashlib.sha256()
    for path in [*sorted(AVR_DIR.glob("*/*.[ch]")), AVR_DIR / "Makefile"]:
        key.update(str(path.relative_to(AVR_DIR)).encode() + path.read_bytes())
    for board, targets in boards:
        key.update(Path(board).read_bytes() + " ".join(targets).encode())
    out = root / f"avr-{key.hexdigest()[:16]}"
    out.mkdir(parents=True, exist_ok=True)
    with open(out / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # (released when the file is closed)
        if not (out / ".built").exists():
            for board, targets in boards:
                make = ["make", "-C", str(AVR_DIR), f"BOARD={Path(board).resolve()}"]
                make += [f"BUILD={out}", f"PYTHON={sys.executable}", *targets]
                r = subprocess.run(make, capture_output=True, text=True, timeout=600)
                with open(out / "build.log", "a") as log:
                    log.write(r.stdout + r.stderr)
                if r.returncode != 0:
                    raise RuntimeError(f"{' '.join(make)}:\n{r.stdout}{r.stderr}")
            (out / ".built").write_text("")
    return out
