"""A virtual board dials its daemon too (board --dial), and comes back after a restart (the
board's and the daemon's sides: tests/test_dial.py)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from missing_link.daemon.session.status import SessionState

from .helpers import wait_for
from .test_dial import listening


# ---- a virtual board dials too -----------------------------------------------------------------
def board_process(*args: str) -> subprocess.Popen[str]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "missing_link", "board", *args],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    assert proc.stdout is not None
    line = proc.stdout.readline()
    assert line.startswith("DIALING tcp://127.0.0.1:"), line + (
        proc.stderr.read() if proc.stderr else ""
    )
    return proc


@pytest.mark.slow
def test_a_virtual_board_dials_in_and_comes_back_after_a_restart() -> None:
    with listening("tcp://127.0.0.1:0") as d:
        assert d.dialins is not None
        url = f"tcp://127.0.0.1:{d.dialins.listener.port}"
        proc = board_process("--sim", "thesis", "--seed", "4", "--dial", url)
        try:
            assert wait_for(lambda: d.sessions and d.wait_until_up(0.1), 20), d.status()
            (s,) = d.sessions
            assert s.name == "thesis" and s.identity.board_id == "sim-thesis-4"
            proc.kill()
            proc.wait(10)
            assert wait_for(lambda: s.state != SessionState.UP, 10)
            proc = board_process("--sim", "thesis", "--seed", "4", "--dial", url)
            assert wait_for(lambda: s.state == SessionState.UP and s.connects == 2, 20), d.status()
            assert len(d.sessions) == 1
        finally:
            proc.kill()
            proc.wait(10)
            for f in (proc.stdout, proc.stderr):
                if f is not None:
                    f.close()
