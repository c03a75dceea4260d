"""What the MicroPython firmware costs on the board side, measured in the real MicroPython
interpreter (1.27, WebAssembly port under node: the firmware and its runtime run unchanged),
with CPython running the same code as the reference in the same run.

    .venv/bin/python bench/bench_firmware.py

Per-sample cost: record a value, poll (assemble the SIF), take the bytes (one int32 channel;
seven floats as the MPU-6050 sends).  Per received byte: an a2jClock request fed and answered.
After t3: from a2jClock's t3 stamp to the reply's bytes in hand (the board's share of the return
trip, which clock sync cannot see).
Heap: gc.mem_free() before and after building the thesis rig's firmware from its board file.
Flash: the bytes `missing-link flash` copies for that board file (.py sources).
These are interpreter figures on this machine's CPU, not a microcontroller's: an RP2040 at
125 MHz is far slower (see docs/hardware.md)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RIG = ROOT / "examples" / "boards" / "thesis-rig.py"
PROBE = ROOT / "bench" / "firmware_probe.py"


def run(cmd: list[str]) -> dict[str, float]:
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=600, check=True).stdout
    return {k: float(v) for k, v in (line.split() for line in out.splitlines() if line.strip())}


def main() -> None:
    from missing_link.deploy.boardfile import load_board_file
    from missing_link.deploy.flash import micropython_files

    host = ROOT / "src" / "missing_link" / "virtual" / "world" / "host.mjs"
    mpy = run(["node", str(host), str(RIG), "--run", str(PROBE)])
    ref = run([sys.executable, str(PROBE), str(ROOT / "src")])
    files = micropython_files(load_board_file(RIG))
    flash = sum(c.local.stat().st_size for c in files)
    print("| board side | MicroPython 1.27 (wasm) | CPython (reference, same code) |")
    print("|---|---|---|")
    for key, label in (
        ("us_per_sif_1ch", "µs per sample SIF, 1 x int32"),
        ("us_per_sif_7ch", "µs per sample SIF, 7 x float (IMU)"),
        ("us_per_rx_byte", "µs per received byte (a2jClock request)"),
        ("us_after_t3", "µs from a2jClock's t3 stamp to its reply's bytes"),
    ):
        print(f"| {label} | {mpy[key]:.2f} | {ref[key]:.2f} |")
    rate, ref_rate = 1e6 / mpy["us_per_sif_1ch"], 1e6 / ref["us_per_sif_1ch"]
    print(f"| max SIF rate, 1 x int32 (1 / cost) | {rate:,.0f} /s | {ref_rate:,.0f} /s |")
    print(f"| heap for the thesis rig's firmware | {mpy['heap_rig'] / 1024:.1f} KiB | - |")
    print(f"| flash: files copied ({len(files)}) | {flash / 1024:.1f} KiB of .py | - |")


if __name__ == "__main__":
    main()
