"""Garbage-collection pauses of the MicroPython firmware in a Raspberry Pi Pico's heap, run
in the real MicroPython interpreter (1.27, WebAssembly port under node) with the simulator's
``--heap 209936 --fast`` (src/missing_link/virtual/world/host.mjs), against a board file with no
transducers as the reference in the same run.

    .venv/bin/python bench/bench_gc.py [SECONDS]

Each board runs SECONDS simulated seconds (default 60) with nobody connected (its SIFs queue
and are dropped, as on a board with no host).  On this port a collection runs when a step
returns to node (simgc.py); a pause is what the simulator's cost model makes of it for the heap
as it was (simcost.py: a Pico's, estimated, from the live blocks and the heap's size), the
firmware's own (board/memory.py) or the allocator's: the same on any machine, and not measured
on a Pico (docs/hardware.md, "Memory")."""

from __future__ import annotations

import ast
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
HOST = ROOT / "src" / "missing_link" / "virtual" / "world" / "host.mjs"
PICO = 209_936
EMPTY = 'BOARD = {"name": "empty", "mcu": "rp2040", "transducers": []}\n'


def run(board: Path, seconds: float) -> dict[str, float]:
    proc = subprocess.Popen(
        ["node", str(HOST), str(board), "--heap", str(PICO), "--fast"],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
    )  # fmt: skip
    assert proc.stdin is not None and proc.stdout is not None
    try:
        assert proc.stdout.readline().startswith("LISTEN ")

        def ask(what: object) -> str:
            proc.stdin.write(json.dumps(what) + "\n")  # type: ignore[union-attr]
            proc.stdin.flush()  # type: ignore[union-attr]
            return proc.stdout.readline()[3:]  # type: ignore[union-attr]

        while int(ask({"sim": "time"})) < seconds * 1e6:
            time.sleep(0.5)
        gc = json.loads(ask({"sim": "gc"}))
        heap = ast.literal_eval(ask("import gc\nresult = (gc.mem_alloc(), rt.memory.longest_us)"))
    finally:
        proc.kill()
        proc.wait()
    us = sorted(gc["us"][1:])  # (the first: the boot's, with its modules' compilation garbage)
    return {
        "live": heap[0],
        "n": len(us) / seconds,
        "p50": statistics.median(us),
        "p99": us[int(len(us) * 0.99)],
        "max": us[-1],
        "auto": gc["collections"]["auto"],
        "firmware_longest": heap[1],
    }


def main() -> None:
    seconds = float(sys.argv[1]) if len(sys.argv) > 1 else 60.0
    with tempfile.TemporaryDirectory() as tmp:
        empty = Path(tmp) / "empty.py"
        empty.write_text(EMPTY)
        rows = [("no transducers (reference)", run(empty, seconds))]
        for name in ("thesis-rig.py", "rover.py"):
            rows.append((name, run(ROOT / "examples" / "boards" / name, seconds)))
    print(f"| board ({seconds:g} simulated s, {PICO} B heap) | allocated | collections/s | "
          "pause p50 | p99 | max | allocator's own | firmware's longest |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|")
    for name, r in rows:
        print(
            f"| {name} | {r['live'] / 1024:.1f} KiB | {r['n']:.1f} | {r['p50']:.0f} µs | "
            f"{r['p99']:.0f} µs | {r['max']:.0f} µs | {r['auto']:.0f} | "
            f"{r['firmware_longest']:.0f} µs |"
        )


if __name__ == "__main__":
    main()
