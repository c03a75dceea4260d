"""Virtual boards in processes of their own (``missing-link board`` in a child), behind real
pseudo-terminals or sockets: what the demo, the benchmarks and the multi-process tests run."""

from __future__ import annotations

import subprocess
import sys
import threading

from ..errors import MissingLinkError


def start_board_process(
    sim: str,
    seed: int,
    listen: str = "pty",
    name: str | None = None,
    timeout: float = 10.0,
    extra: list[str] | None = None,
) -> tuple[subprocess.Popen[str], str]:
    """Start ``missing-link board`` in a child process; return it and the URL it printed."""
    cmd = [sys.executable, "-m", "missing_link", "board", "--sim", sim, "--seed", str(seed)]
    cmd += ["--listen", listen] + (["--name", name] if name else []) + (extra or [])
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines: list[str] = []
    reader = threading.Thread(
        target=lambda: lines.append(proc.stdout.readline() if proc.stdout else ""), daemon=True
    )
    reader.start()
    reader.join(timeout)
    line = lines[0] if lines else ""
    if not line.startswith("LISTENING "):
        proc.kill()
        err = proc.stderr.read() if proc.stderr else ""
        raise MissingLinkError(f"virtual board did not start (got {line!r}); stderr: {err.strip()}")
    return proc, line.split(" ", 1)[1].strip()


def stop_process(proc: subprocess.Popen[str]) -> None:
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
