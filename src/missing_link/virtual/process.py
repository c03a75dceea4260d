"""Virtual boards in processes of their own (``missing-link board`` in a child), behind real
pseudo-terminals or sockets: what the demo, the benchmarks and the multi-process tests run."""

from __future__ import annotations

import subprocess
import sys
import threading
from typing import Any

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


def hang_up(proc: subprocess.Popen[Any]) -> None:
    """Close the child's stdin, the end our children take as "power off" (a pipe already broken
    means it is going anyway)."""
    try:
        if proc.stdin is not None:
            proc.stdin.close()
    except (OSError, ValueError):
        pass


def reap(proc: subprocess.Popen[Any], grace: float = 5.0) -> int:
    """Wait up to ``grace`` seconds for the child to end by itself, then kill it; its exit code.
    No child outlives its owner, and none is left a zombie."""
    try:
        return proc.wait(grace)
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.wait(5)


def stop_process(proc: subprocess.Popen[Any], grace: float = 5.0) -> None:
    """SIGTERM, then :func:`reap` (SIGKILL after ``grace`` seconds)."""
    if proc.poll() is None:
        proc.terminate()
    reap(proc, grace)
