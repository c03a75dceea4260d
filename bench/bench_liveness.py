"""Liveness: how long after a board freezes, or its link goes half-open, the daemon says it is lost.

    .venv/bin/python bench/bench_liveness.py [--trials 10] [--kinds thesis,rangers,micropython,avr]
        [--faults freeze,half-open] [--busy]

Each board kind runs as a real process the daemon connects to, as in the tests:

  thesis       ``missing-link board --sim thesis`` (a servo: the board has a failsafe)
  rangers      ``missing-link board --sim rangers`` (no actuator)
  micropython  the MicroPython firmware of examples/boards/thesis-rig.py under node (a servo)
  avr          the AVR firmware of examples/boards/thesis-rig-uno.py in simavr (a servo)

A trial waits until the board is up and has run for 1-1.5 s (random: the freeze falls anywhere
in the daemon's second), then makes the fault: ``freeze`` is SIGSTOP of the board's process,
``half-open`` a fault relay in front of it that stops forwarding with both sockets open (TCP
kinds only).  The time until the session leaves ``up`` is the detection latency; then SIGCONT
(or the relay forwards again) and the next trial waits for the board to be up again.

``--busy``: while the trial runs, the servo (where there is one) is commanded every 20 ms, and
right after the fault a control call (``Daemon.call``, as the control endpoint makes it) with a
10 s timeout is in flight.

The reference is the daemon's own promise, printed in the same run: ``link_timeout`` (1.5 s by
default) and the bound ``link_timeout + 0.5 s``.  Run it against an older tree with
``PYTHONPATH=<that tree>/src`` to compare.
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
from tests.helpers import AvrSim, FirmwareSim  # noqa: E402  (the harness drivers the tests use)

from missing_link.daemon import Daemon  # noqa: E402
from missing_link.daemon.config import BoardSpec, Config  # noqa: E402
from missing_link.deploy.avr import AVR_DIR  # noqa: E402
from missing_link.errors import MissingLinkError  # noqa: E402
from missing_link.virtual.faults import FaultRelay  # noqa: E402

KINDS = ("thesis", "rangers", "micropython", "avr")
SERVO = {
    "thesis": "/thesis/servo/cmd",
    "micropython": "/rig/servo/cmd",
    "avr": "/uno_rig/servo/cmd",
}


class Kind:
    """A board process: its URL, how to freeze and thaw it, how to end it."""

    def __init__(self, url: str, pid: int, close: Callable[[], None], **spec: object) -> None:
        self.url, self.pid, self.close, self.spec = url, pid, close, spec


def start_kind(kind: str, build: Path | None) -> Kind:
    if kind in ("thesis", "rangers"):
        p = subprocess.Popen(
            [sys.executable, "-m", "missing_link", "board", "--listen", "tcp://127.0.0.1:0",
             "--sim", kind],
            stdout=subprocess.PIPE, text=True,
        )  # fmt: skip
        assert p.stdout is not None
        line = p.stdout.readline()
        if not line.startswith("LISTENING "):
            raise SystemExit(f"{kind}: board did not start: {line!r}")

        def stop() -> None:
            p.send_signal(signal.SIGCONT)
            p.terminate()
            p.wait(10)

        return Kind(line.split()[1], p.pid, stop)
    if kind == "micropython":
        sim = FirmwareSim(ROOT / "examples" / "boards" / "thesis-rig.py")
        return Kind(sim.url, sim.proc.pid, lambda: _thaw_then(sim.proc.pid, sim.close))
    assert build is not None
    rig = AvrSim(build, build / "uno_rig" / "firmware.elf")

    def close() -> None:
        _thaw_then(rig.proc.pid, rig.close)

    return Kind(rig.url, rig.proc.pid, close, uart_baud=115200)


def _thaw_then(pid: int, close: Callable[[], None]) -> None:
    try:
        os.kill(pid, signal.SIGCONT)
    except ProcessLookupError:
        pass
    close()


def build_avr(out: Path) -> Path:
    uno = ROOT / "examples" / "boards" / "thesis-rig-uno.py"
    subprocess.run(
        ["make", "-C", str(AVR_DIR), f"BOARD={uno}", f"BUILD={out}",
         f"PYTHON={sys.executable}", "all", "sim"],
        check=True, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    return out


@contextmanager
def busy(d: Daemon, kind: str, on: bool) -> Iterator[Callable[[str], None]]:
    """Commands every 20 ms while on; yields ``call(board)``: a control call in flight."""
    stop = threading.Event()
    topic = SERVO.get(kind)

    def command() -> None:
        k = 0
        while not stop.wait(0.02):
            try:
                d.send(topic, (k % 60) - 30)  # type: ignore[arg-type]
            except (KeyError, MissingLinkError):
                pass  # (not up: no command topic)
            k += 1

    def control_call(board: str) -> None:
        def run() -> None:
            try:
                d.call(board, "a2jEcho", b"", timeout=10.0)
            except (MissingLinkError, ValueError):
                pass

        threading.Thread(target=run, daemon=True).start()

    t = threading.Thread(target=command, daemon=True)
    if on and topic is not None:
        t.start()
    try:
        yield control_call if on else (lambda board: None)
    finally:
        stop.set()


def trials(kind: str, fault: str, n: int, busy_on: bool, build: Path | None) -> list[float]:
    board = start_kind(kind, build)
    relay = FaultRelay(board.url).start() if fault == "half-open" else None
    url = relay.url if relay is not None else board.url
    out: list[float] = []
    rng = random.Random(1)
    try:
        with (
            Daemon(Config(boards=[BoardSpec(url, **board.spec)])) as d,  # type: ignore[arg-type]
            busy(d, kind, busy_on) as control_call,
        ):
            s = d.sessions[0]
            for _ in range(n):
                if not _wait(lambda: s.state == "up", 60):
                    raise SystemExit(f"{kind}: not up again: {s.error}")
                time.sleep(1.0 + 0.5 * rng.random())
                if relay is not None:
                    relay.blackhole(True)
                else:
                    board_signal(board.pid, signal.SIGSTOP)
                t0 = time.monotonic()
                control_call(s.name)
                lost = _wait(lambda: s.state != "up", 60, 0.005)
                out.append(time.monotonic() - t0 if lost else float("inf"))
                if relay is not None:
                    relay.blackhole(False)
                else:
                    board_signal(board.pid, signal.SIGCONT)
    finally:
        if relay is not None:
            relay.stop()
        board.close()
    return out


def board_signal(pid: int, sig: signal.Signals) -> None:
    os.kill(pid, sig)


def _wait(cond: Callable[[], bool], timeout: float, step: float = 0.02) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(step)
    return cond()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--trials", type=int, default=10)
    ap.add_argument("--kinds", default=",".join(KINDS))
    ap.add_argument("--faults", default="freeze,half-open")
    ap.add_argument("--busy", action="store_true")
    args = ap.parse_args()
    kinds = [k for k in args.kinds.split(",") if k]
    faults = [f for f in args.faults.split(",") if f]
    link_timeout = BoardSpec("x").link_timeout
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        build = build_avr(Path(tmp)) if "avr" in kinds else None
        for kind in kinds:
            for fault in faults:
                if fault == "half-open" and kind == "avr":
                    continue  # (a pty: no relay; a frozen simulator is the same silence)
                got = trials(kind, fault, args.trials, args.busy, build)
                rows.append((kind, fault, got))
                print(f"  {kind} {fault}: " + " ".join(f"{x:.2f}" for x in got), flush=True)
    print(f"\nlink_timeout {link_timeout:.2f} s (reference); bound {link_timeout + 0.5:.2f} s; "
          f"busy={args.busy}")  # fmt: skip
    print(f"| kind | fault | trials | min s | median s | max s | over {link_timeout + 0.5:.1f} s |")
    print("|---|---|---|---|---|---|---|")
    for kind, fault, got in rows:
        over = sum(1 for x in got if x > link_timeout + 0.5)
        print(f"| {kind} | {fault} | {len(got)} | {min(got):.2f} | {statistics.median(got):.2f} "
              f"| {max(got):.2f} | {over} |")  # fmt: skip


if __name__ == "__main__":
    main()
