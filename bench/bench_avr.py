"""The AVR firmware measured on real AVR machine code (simavr, ATmega328P at 16 MHz, the UART on a
pseudo-terminal), with the reference in the same run: the UART's own byte rate.

    .venv/bin/python bench/bench_avr.py [--seconds 5]

* flash and RAM of the thesis-rig firmware on ATmega328P and ATmega2560 (avr-size, static RAM);
* the SIF rate the board sustains with one encoder transducer asked for 20 kHz, at 115200 baud
  and 1 Mbaud, against the line's byte rate / the SIF's bytes (the reference);
* CPU cycles per received byte (parse and answer, a2jEcho with 16 bytes) and per sample SIF
  written (a profiling build: Timer1 ticks around runtime_feed / the SIF encoder);
* clock sync against the simulated crystal (80 ppm fast): the daemon's map of the simulator's own
  (board µs, host ns) readings, taken at the same instant in the simulator thread, after 8 s.

``--reference DIR``: the same figures for the firmware of another source tree (``git worktree
add DIR COMMIT``, or ``git archive COMMIT | tar -x -C DIR``), built by its own Makefile and
generator and run in this tree's rig in the same run, side by side: the cycle counts are
simulated cycles, so a busy machine changes the rates, not them."""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
from tests.helpers import AvrSim  # noqa: E402  (the harness driver the tests use)

from missing_link.daemon import Daemon  # noqa: E402
from missing_link.daemon.config import BoardSpec, Config  # noqa: E402
from missing_link.deploy.avr import AVR_DIR as AVR  # noqa: E402
from missing_link.host.board import Board  # noqa: E402
from missing_link.transport import open_transport  # noqa: E402

BOARDS = ROOT / "examples" / "boards"


def firmware_dir(tree: Path | None) -> Path:
    """The AVR firmware of a source tree (this one's: None); older trees had it at the top."""
    if tree is None:
        return AVR
    inside = tree / "src" / "missing_link" / "firmware" / "avr"
    return inside if inside.is_dir() else tree / "firmware" / "avr"


def make(board: Path, build: Path, extra: str = "", tree: Path | None = None) -> str:
    """Build ``board`` (and the rig, into build) with the firmware and generator of ``tree``."""
    cmd = ["make", "-C", str(firmware_dir(tree)), f"BOARD={board}", f"BUILD={build}",
           f"PYTHON={sys.executable}"]  # fmt: skip
    if extra:
        cmd.append(f"EXTRA_CFLAGS={extra}")
    env = dict(os.environ)
    if tree is not None:  # (its own generator: board_gen.c must match its C)
        env["PYTHONPATH"] = str(tree / "src")
    out = subprocess.run(
        [*cmd, "all", "sim"], capture_output=True, text=True, check=True, env=env
    ).stdout
    return next(line for line in out.splitlines() if ": flash " in line)


def variant(tmp: Path, name: str, baud: int, boards: Path = BOARDS) -> Path:
    text = (boards / "thesis-rig-uno.py").read_text()
    text = text.replace('"name": "uno_rig"', f'"name": "{name}"')
    text = text.replace('"baudrate": 115200', f'"baudrate": {baud}')
    text = text.replace('"pin_b": 3, "rate_hz": 50', '"pin_b": 3, "rate_hz": 20000')
    p = tmp / f"{name}.py"
    p.write_text(text)
    return p


def peek_u32(sim: AvrSim, elf: Path, symbol: str) -> int:
    nm = subprocess.run(["avr-nm", str(elf)], capture_output=True, text=True, check=True).stdout
    addr = next(
        int(line.split()[0], 16) & 0xFFFF for line in nm.splitlines() if line.endswith(" " + symbol)
    )
    b = sim.ctl(f"peek {addr:x}").split()[1:5]
    return int.from_bytes(bytes(int(x, 16) for x in b), "little")


def sif_rate(
    build: Path, name: str, baud: int, seconds: float, rig: Path
) -> tuple[float, float, int]:
    """(SIFs/s received, cycles per SIF written, SIF bytes); rig: where rig_sim is"""
    elf = build / name / "firmware.elf"
    sim = AvrSim(rig, elf)
    try:
        board = Board(open_transport(f"{sim.url}?baud={baud}"), timeout=3.0)
        board.handshake()
        count = [0]
        size = [0]

        def on(sif, _rx) -> None:  # type: ignore[no-untyped-def]
            if sif.cmd == 0:
                count[0] += 1
                size[0] = len(sif.payload)

        board.on_sif(0, on)
        time.sleep(1.0)
        c0, t0 = count[0], time.monotonic()
        time.sleep(seconds)
        rate = (count[0] - c0) / (time.monotonic() - t0)
        ticks, sifs = peek_u32(sim, elf, "prof_sif_ticks"), peek_u32(sim, elf, "prof_sifs")
        board.close()
        return rate, ticks * 8 / max(1, sifs), size[0]
    finally:
        sim.close()


def rx_cycles(build: Path, name: str, rig: Path) -> float:
    elf = build / name / "firmware.elf"
    sim = AvrSim(rig, elf)
    try:
        board = Board(open_transport(sim.url), timeout=3.0)
        board.handshake()
        b0 = peek_u32(sim, elf, "prof_feed_bytes")
        k0 = peek_u32(sim, elf, "prof_feed_ticks")
        for _ in range(200):
            board.call("a2jEcho", bytes(range(16)))
        b1 = peek_u32(sim, elf, "prof_feed_bytes")
        k1 = peek_u32(sim, elf, "prof_feed_ticks")
        board.close()
        return (k1 - k0) * 8 / max(1, b1 - b0)
    finally:
        sim.close()


def wander_us(pairs: list[tuple[int, int]]) -> float:
    """Largest distance (µs) of the simulator's own (board µs, host ns) readings from their best
    straight line: how far the paced simulated clock itself strays from a steady clock."""
    n = len(pairs)
    xs = [h / 1000 for _, h in pairs]
    ys = [b for b, _ in pairs]
    mx, my = sum(xs) / n, sum(ys) / n
    k = sum((x - mx) * (y - my) for x, y in zip(xs, ys, strict=True)) / sum(
        (x - mx) ** 2 for x in xs
    )
    return max(abs(y - (my + k * (x - mx))) for x, y in zip(xs, ys, strict=True))


def sync_accuracy(build: Path, rig: Path) -> tuple[list[float], list[float], float, float]:
    """(|error| µs, bound µs, skew ppm, simulator wander µs) for the daemon's map of the
    simulator's readings."""
    sim = AvrSim(rig, build / "uno_rig" / "firmware.elf", skew_ppm=80.0)
    errs, bounds, pairs = [], [], []
    try:
        with Daemon(Config(boards=[BoardSpec(sim.url, timeout=2.0, uart_baud=115200)])) as d:
            assert d.wait_until_up(20)
            time.sleep(8.0)
            sync = d.sessions[0].sync
            assert sync is not None
            for _ in range(40):
                f = sim.ctl("stats").split()
                board_us, host_ns = int(f[2]), int(f[4])
                pairs.append((board_us, host_ns))
                m = sync.map(board_us)
                if m is not None and m.bound_ns >= 0:
                    errs.append(abs(m.host_ns - host_ns) / 1000)
                    bounds.append(m.bound_ns / 1000)
                time.sleep(0.25)
            skew = d.status()[0]["skew_ppm"]
    finally:
        sim.close()
    return errs, bounds, skew, wander_us(pairs)


def measure(tmp: Path, tree: Path | None, seconds: float) -> dict[str, object]:
    """One firmware's figures: sizes, SIF rates and cycles, cycles per byte received."""
    out = tmp / ("reference" if tree is not None else "now")
    out.mkdir()
    boards = BOARDS if tree is None else tree / "examples" / "boards"  # (its own board files)
    sizes = [make(boards / "thesis-rig-uno.py", out, tree=tree),
             make(boards / "thesis-rig-mega.py", out, tree=tree)]  # fmt: skip
    rows = []
    for baud in (115200, 1000000):
        name = f"rate_{baud}"
        make(variant(out, name, baud, boards), out, "-DJ2A_PROFILE", tree)
        rows.append((baud, *sif_rate(out, name, baud, seconds, tmp)))
    return {"sizes": sizes, "rows": rows, "per_byte": rx_cycles(out, "rate_115200", tmp),
            "sync": sync_accuracy(out, tmp)}  # fmt: skip


def print_figures(label: str, got: dict[str, object]) -> None:
    print(f"**{label}**")
    print()
    print("| firmware (thesis rig) | flash | static RAM |")
    print("|---|---|---|")
    for line in got["sizes"]:  # type: ignore[attr-defined]
        m = re.match(r"(\S+): flash (\d+) of (\d+) bytes, RAM (\d+) of (\d+)", line)
        assert m
        mcu, fl, fmax, ram, rmax = m.groups()
        print(f"| {mcu} | {int(fl):,} of {int(fmax):,} B | {int(ram):,} of {int(rmax):,} B |")
    print()
    print(
        "| UART | SIFs/s sustained (1 x int32) | line limit (reference) | cycles per SIF written |"
    )
    print("|---|---|---|---|")
    for baud, rate, cyc, size in got["rows"]:  # type: ignore[attr-defined]
        frame = 1 + 3 + size + 1  # SOS, seq/cmd/len, payload, checksum (no escapes counted)
        print(f"| {baud} | {rate:,.0f} | {baud / 10 / frame:,.0f} | {cyc:,.0f} |")
    print()
    print(f"cycles per received byte (parse + answer, a2jEcho 16 B): {got['per_byte']:,.0f}")
    print()
    errs, bounds, skew, wander = got["sync"]  # type: ignore[misc]
    inside = sum(e <= b for e, b in zip(errs, bounds, strict=True)) / len(errs) * 100
    errs.sort()
    p = lambda q: errs[min(len(errs) - 1, int(q * len(errs)))]  # noqa: E731
    print(
        f"clock sync, 115200 baud, crystal +80 ppm: error p50 {p(0.5):.0f} µs, p99 {p(0.99):.0f}"
        f" µs, max {errs[-1]:.0f} µs; bound p50 {statistics.median(bounds):.0f} µs; "
        f"in bound {inside:.0f} %; "
        f"skew estimate {skew:.1f} ppm ({len(errs)} readings over 10 s); the simulated clock "
        f"itself strays up to {wander:.0f} µs from a straight line (pacing on this machine)"
    )
    print()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--reference", type=Path, help="another source tree, measured beside")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp_s:
        tmp = Path(tmp_s)  # (this tree's rig_sim, in tmp, runs both firmwares)
        subprocess.run(
            ["make", "-C", str(AVR), "sim", f"BUILD={tmp}"], capture_output=True, check=True
        )
        ref = measure(tmp, a.reference.resolve(), a.seconds) if a.reference else None
        now = measure(tmp, None, a.seconds)
    if ref is not None:
        print_figures(f"reference: {a.reference}", ref)
    print_figures("this tree", now)


if __name__ == "__main__":
    main()
