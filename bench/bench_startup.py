"""Start-up: a whole ``missing-link call`` process against a virtual board on TCP, and
``import missing_link``, next to a bare ``python -c pass`` (the floor, same run), each run as
its own process with the bytecode cached (PYTHONDONTWRITEBYTECODE removed).  With ``--base``
(another checkout's venv, e.g. of the commit before a change) every command runs there too,
alternated A B A B, and the ratio A/B is given pair by pair: the machine's drift cancels.

    .venv/bin/python bench/bench_startup.py [--runs 20] [--base ../base/.venv]

Wall time by the clock around each child, CPU time from getrusage(RUSAGE_CHILDREN).
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

from missing_link.virtual.process import start_board_process, stop_process

Run = tuple[float, float]  # (wall s, cpu s)


def run_once(cmd: list[str], env: dict[str, str]) -> Run:
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def commands(venv: Path, url: str) -> dict[str, list[str]]:
    py = str(venv / "bin" / "python")
    return {
        "python -c pass (the floor)": [py, "-c", "pass"],
        'python -c "import missing_link"': [py, "-c", "import missing_link"],
        "missing-link call URL a2jEcho": [
            str(venv / "bin" / "missing-link"),
            "call",
            url,
            "a2jEcho",
        ],
    }


def spread(values: list[float]) -> str:
    ms = [v * 1000 for v in values]
    return f"{min(ms):.1f} / {statistics.median(ms):.1f} / {max(ms):.1f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--base", type=Path, help="another checkout's venv: run its commands too")
    a = ap.parse_args()
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env["MISSING_LINK_CONTROL"] = "/nonexistent/missing-link-bench.sock"  # (no daemon asked)
    proc, url = start_board_process("thesis", 0, "tcp://127.0.0.1:0")
    try:
        here = commands(Path(sys.prefix), url)
        base = commands(a.base, url) if a.base else None
        print(f"| command (ms: min / median / max of {a.runs}) | wall | cpu |", end="")
        print(" base wall | base cpu | A/B wall, median |" if base else "")
        print("|---|---|---|" + ("---|---|---|" if base else ""))
        for name, cmd in here.items():
            other = base[name] if base else None
            for _ in range(2):  # warm-up: the bytecode written, the page cache warm
                run_once(cmd, env)
                if other:
                    run_once(other, env)
            mine: list[Run] = []
            theirs: list[Run] = []
            for _ in range(a.runs):
                mine.append(run_once(cmd, env))
                if other:
                    theirs.append(run_once(other, env))
            row = f"| {name} | {spread([w for w, _ in mine])} | {spread([c for _, c in mine])} |"
            if theirs:
                ratio = statistics.median(m[0] / t[0] for m, t in zip(mine, theirs, strict=True))
                row += f" {spread([w for w, _ in theirs])} | {spread([c for _, c in theirs])} |"
                row += f" {ratio:.2f} |"
            print(row, flush=True)
    finally:
        stop_process(proc)


if __name__ == "__main__":
    main()
