"""The rover's and the thesis rig's ten-minute soaks (tests/test_memory.py), in the background.

Each soak is a process of its own (``python -m tests.soak_runner NAME OUT``: the simulator and
the host of memory_soak.py), started when the session's tests have been collected (conftest.py
``pytest_collection_finish``), so ten simulated minutes of both boards, about a minute and a half
of CPU each, run beside the rest of the suite instead of holding it up.  They run under
SCHED_IDLE: only on a CPU nothing else wants, and a waking test process always goes first.
(At nice 19 they did not: their processes sleep and wake every few milliseconds and kept their
share, and simavr, which must keep up with real time, fell behind beside them: AVR tests
failed.)  The soak's results do not depend on its pace (the simulated clock is the simulator's
own CPU time, fastclock.mjs; the host takes its turns on that clock).  test_memory.py waits
for them and checks what they found.  Only the soaks the session selected start (``-m "not
slow"`` starts none); a soak whose test is not reached is stopped at the session's end.
"""

from __future__ import annotations

import os
import pickle
import shutil
import struct
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

from missing_link.deploy.heap import FREE_HEAP
from missing_link.host.board import Board

from .memory_soak import STALL_S, FastSim, Soaked, soak

ROOT = Path(__file__).resolve().parent.parent
BOARDS = ROOT / "examples" / "boards"
PICO = FREE_HEAP["rp2040"].bytes
MINUTES = 10


def _rover_commands(board: Board, turn: int) -> int:
    """The rover's host: the motors back and forth, the mast round, the wheels turning."""
    if turn % 20:
        return 0
    speed = struct.pack("<f", 0.6 if turn % 40 else -0.6)
    board.call_ok("a2j_motor_l", speed)
    board.call_ok("a2j_motor_r", speed)
    board.call_ok("a2j_mast", struct.pack("<f", (turn // 20) % 4 * 0.25))
    return 3


def _rig_commands(board: Board, turn: int) -> int:
    """The rig's host: the servo swept, the camera triggered at a host time (a timed call)."""
    if turn % 20:
        return 0
    board.call_ok("a2j_set_servo", struct.pack("<b", (turn // 20) % 200 - 100))
    now = board.clock_exchange(STALL_S).t3  # (a second ahead: the board may run LEAD_MS ahead)
    at = struct.pack("<qB", (now + 1_000_000) * 1000, board.index["a2j_trigger"])
    board.call_ok("a2jAt", at + struct.pack("<H", 100))
    return 2


def _turn_wheels(sim: FastSim, pins: list[tuple[int, int]]) -> Callable[[Board, int], int]:
    def act(board: Board, turn: int) -> int:
        if turn % 50 == 0:
            for a, b in pins:
                sim.ctl(f"WORLD.encoder_steps({a}, {b}, {turn % 37 + 1})")
        return 0

    return act


def _soaked(
    board_file: str,
    aligned: list[str],
    commands: Callable[[Board, int], int],
    wheels: list[tuple[int, int]],
) -> Soaked:
    sim = FastSim(BOARDS / board_file, PICO)
    try:
        turn_wheels = _turn_wheels(sim, wheels)
        res = soak(sim, MINUTES * 60, aligned, lambda b, t: commands(b, t) + turn_wheels(b, t))
        gc = sim.figure("gc")
        assert sim.ctl("result = 1") == 1  # (the firmware still steps: no CRASH, no BREAK)
    finally:
        sim.close()
    return Soaked(res, gc, "".join(sim.stderr))


ROVER_ALIGNED = ["compass", "wheel_l", "wheel_r"]  # 50 Hz: an instant every 20 ms
RIG_ALIGNED = ["imu", "dist_ir", "wheel"]  # 100, 25 and 50 Hz: an instant every 10 ms
SOAKS: dict[str, Callable[[], Soaked]] = {
    "rover": lambda: _soaked("rover.py", ROVER_ALIGNED, _rover_commands, [(2, 3), (6, 7)]),
    "rig": lambda: _soaked("thesis-rig.py", RIG_ALIGNED, _rig_commands, [(2, 3)]),
}


class Background:
    """The selected soaks' processes, and where each leaves its result and its log."""

    def __init__(self, names: list[str]) -> None:
        self.dir = Path(tempfile.mkdtemp(prefix="ml-soak-"))
        self.procs: dict[str, subprocess.Popen[bytes]] = {}
        for name in names:
            with open(self.dir / f"{name}.log", "wb") as log:
                self.procs[name] = subprocess.Popen(
                    [sys.executable, "-m", "tests.soak_runner", name, str(self.dir / name)],
                    cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                )  # fmt: skip

    def result(self, name: str, timeout: float) -> Soaked:
        """The soak's result, once its process has ended; a failed soak's log in the error."""
        if name not in self.procs:  # (selected after collection: a test run by itself)
            raise RuntimeError(f"soak {name!r} was not started at collection")
        rc = self.procs[name].wait(timeout)
        out = self.dir / name
        if rc != 0 or not out.exists():
            log = (self.dir / f"{name}.log").read_text(errors="replace")
            raise RuntimeError(f"soak {name} failed (exit {rc}):\n{log[-4000:]}")
        with open(out, "rb") as f:
            got = pickle.load(f)
        assert isinstance(got, Soaked)
        return got

    def stop(self) -> None:
        for proc in self.procs.values():
            if proc.poll() is None:
                proc.kill()
                proc.wait(10)
        shutil.rmtree(self.dir, ignore_errors=True)


_started: Background | None = None


def start(names: list[str]) -> None:
    """Start these soaks (conftest.py, once the session's tests are known)."""
    global _started
    if names and _started is None:
        _started = Background(names)


def started() -> Background:
    if _started is None:
        raise RuntimeError("no soak was started: conftest.py starts them at collection")
    return _started


def stop() -> None:
    if _started is not None:
        _started.stop()


def main(argv: list[str]) -> int:
    name, out = argv
    os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))  # (inherited by the simulator)
    got = SOAKS[name]()
    tmp = Path(out + ".part")
    with open(tmp, "wb") as f:
        pickle.dump(got, f)
    tmp.rename(out)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
