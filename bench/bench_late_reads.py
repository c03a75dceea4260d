"""How late the thesis rig's aligned ADC reads come in the real-time simulator (no --fast: the
board's clock is this machine's), with the firmware's own garbage collection (board/memory.py)
against the reference of no garbage collection at all (the firmware's off, the interpreter's
disabled: its heap only grows), in the same run.

    .venv/bin/python bench/bench_late_reads.py [SECONDS]

The ranger is aligned at 10 Hz on a host map (as tests/test_firmware.py does); every read's
distance from its grid instant is taken from the simulated device's log (board ticks, whole ms:
the WebAssembly port's real-time clock).  What is late with no collection at all is this
machine's: node waiting for a core."""

from __future__ import annotations

import os
import struct
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from tests.helpers import FirmwareSim  # noqa: E402

from missing_link.host.board import Board  # noqa: E402
from missing_link.transport import open_transport  # noqa: E402

RIG = ROOT / "examples" / "boards" / "thesis-rig.py"
H0 = 1_795_000_000_000_000_000
NO_GC = "rt.memory.period_us = 10**12\nimport simworld.simgc\nsimworld.simgc._gc.disable()"


def offsets(no_gc: bool, seconds: float) -> list[float]:
    """Each aligned read's distance from its grid instant (ms), the first left out."""
    sim = FirmwareSim(RIG)
    board = Board(open_transport(sim.url), timeout=5.0)
    try:
        board.handshake()
        if no_gc:
            sim.ctl(NO_GC + "\nresult = 1")
        now = board.clock_exchange(5.0).t3
        board.call_ok("a2jHostMap", struct.pack("<Qqi", now, H0, 0))
        board_now, raw_now = sim.ctl("import time; result = (rt.clock(), time.ticks_us())")
        board.configure({"dist_ir.aligned": True, "dist_ir.rate_hz": 10, "dist_ir.phase": 0.25})
        sim.ctl("WORLD.adc_log.clear()")
        out: list[float] = []
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            time.sleep(1.0)
            reads = sim.ctl("result = list(WORLD.adc_log)\nWORLD.adc_log.clear()")
            firsts = [t for i, t in enumerate(reads) if i == 0 or t - reads[i - 1] > 5_000]
            for t in firsts:
                host_ns = H0 + (t - raw_now + board_now - now) * 1000
                off = (host_ns - 25_000_000) % 100_000_000
                out.append(min(off, 100_000_000 - off) / 1e6)
            fresh = board.clock_exchange(5.0).t3  # (a map as fresh as a daemon keeps it)
            board.call_ok("a2jHostMap", struct.pack("<Qqi", fresh, H0 + (fresh - now) * 1000, 0))
        return out[1:]
    finally:
        board.close()
        sim.close()


def main() -> None:
    seconds = float(sys.argv[1]) if len(sys.argv) > 1 else 30.0
    print(f"| real-time simulator, {seconds:g} s each (load {os.getloadavg()[0]:.1f}) | reads | "
          "over 2 ms | p99 | max |")  # fmt: skip
    print("|---|---|---|---|---|")
    for name, no_gc in (("no garbage collection (reference)", True), ("board/memory.py", False)):
        offs = sorted(offsets(no_gc, seconds))
        print(
            f"| {name} | {len(offs)} | {sum(o > 2 for o in offs)} | "
            f"{offs[int(len(offs) * 0.99)]:.2f} ms | {offs[-1]:.2f} ms |"
        )


if __name__ == "__main__":
    main()
