"""A new user's first hour: what the CLI and the daemon do when things are not as they should be.
Every message that misses a recording has a number; ``run`` says when a board never came up.

The CLI runs as real processes; the full disk is a real 1 MiB tmpfs (skipped with the reason
where this user may not mount one; ``ML_REQUIRE_TMPFS=1``, as CI sets, makes that a failure)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

ML = [sys.executable, "-m", "missing_link"]


def ml(*args: str, timeout: float = 60, **kw: Any) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*ML, *args], capture_output=True, text=True, timeout=timeout, **kw)


@contextmanager
def board_process(*args: str) -> Iterator[str]:
    p = subprocess.Popen(
        [*ML, "board", "--listen", "tcp://127.0.0.1:0", *args], stdout=subprocess.PIPE, text=True
    )
    try:
        assert p.stdout is not None
        line = p.stdout.readline()
        assert line.startswith("LISTENING "), line
        yield line.split()[1]
    finally:
        p.terminate()
        p.wait(10)


@contextmanager
def tmpfs(where: Path, size: str) -> Iterator[Path]:
    where.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(where)],
                       capture_output=True, text=True)  # fmt: skip
    if r.returncode != 0:
        why = f"cannot mount a tmpfs here: {r.stderr.strip() or r.returncode}"
        if os.environ.get("ML_REQUIRE_TMPFS") == "1":
            raise RuntimeError(f"ML_REQUIRE_TMPFS=1 but {why}")
        pytest.skip(why)
    try:
        yield where
    finally:
        subprocess.run(["umount", "-l", str(where)], check=False)


# ---- 1. a full disk: recorded + dropped, and recover restores exactly the recorded ------------
def test_a_full_disk_counts_every_message_it_could_not_keep(tmp_path: Path) -> None:
    with (
        tmpfs(tmp_path / "disk", "1m") as disk,
        board_process("--sim", "rate", "--rate", "4000", "--channels", "8", "--name", "r") as url,
    ):
        r = ml("run", url, "--record", str(disk / "rec"), "-p", "bus")
        assert r.returncode == 1, r.stderr
        assert "Traceback" not in r.stderr
        assert re.search(r"error: mcap: recording failed: No space left on device", r.stderr)
        pattern = r"publisher mcap: (\d+) messages, (\d+) dropped, recorded (\S+)"
        got = re.search(pattern, r.stderr)
        assert got, r.stderr
        recorded, dropped, bag = int(got[1]), int(got[2]), Path(got[3])
        assert dropped > 0 and recorded > 0
        out = tmp_path / "recovered"
        rec = ml("recover", str(bag), "--out", str(out))
    assert rec.returncode == 0, rec.stderr
    assert rec.stdout.strip() == f"recovered {recorded} messages into {out}"
