"""The simavr rig's link when its pty thread runs late (firmware/avr/sim/link.c).  simavr's
uart_pty keeps the AVR's bytes in a 512-byte FIFO for a thread of its own to write to the
pseudo-terminal, and drops a byte that finds it full: on a busy machine that thread can wait
while the AVR runs on (flat out, when the rig catches up), and the host lost bytes a real board
would have delivered (the host's serial buffers had room).  Here that thread alone is stopped
(ptrace: the simulation's thread runs on) until the FIFO is full: the rig holds the AVR until
the thread drains it, and every byte the AVR sent reaches the host intact."""

from __future__ import annotations

import ctypes
import os
from collections.abc import Iterator
from contextlib import contextmanager

import pytest

from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config

from .helpers import AvrSim, wait_for

pytestmark = [pytest.mark.avr, pytest.mark.slow]

PTRACE_DETACH, PTRACE_SEIZE, PTRACE_INTERRUPT = 17, 0x4206, 0x4207
WALL = 0x40000000  # (waitpid's __WALL: a thread of another process)


@contextmanager
def _stopped(tid: int) -> Iterator[None]:
    """Thread ``tid`` (of a child of ours) stopped, and only it (SIGSTOP would stop them all)."""
    libc = ctypes.CDLL(None, use_errno=True)
    libc.ptrace.argtypes = [ctypes.c_long, ctypes.c_long, ctypes.c_void_p, ctypes.c_void_p]
    for request in (PTRACE_SEIZE, PTRACE_INTERRUPT):
        if libc.ptrace(request, tid, None, None) != 0:
            raise OSError(ctypes.get_errno(), f"ptrace {request:#x} {tid}")
    os.waitpid(tid, WALL)
    try:
        yield
    finally:
        libc.ptrace(PTRACE_DETACH, tid, None, None)


def _uart(rig: AvrSim) -> dict[str, int]:
    """The rig's count of the AVR's bytes: sent, dropped, held (link.h)."""
    words = rig.ctl("uart").split()[1:]
    return {k: int(v) for k, v in zip(words[::2], words[1::2], strict=True)}


def _damage(d: Daemon) -> dict[str, int]:
    """What the host found wrong with the bytes it read."""
    s = d.status()[0]
    return {k: s[k] for k in ("bad_checksums", "bad_escapes", "cut_frames", "junk_bytes")}


def _pty_thread(rig: AvrSim) -> int:
    """simavr's uart_pty thread: the rig's second thread (the first is the simulation's)."""
    tids = sorted(int(t) for t in os.listdir(f"/proc/{rig.proc.pid}/task"))
    assert len(tids) == 2, tids
    return tids[1]


def test_a_late_pty_thread_loses_no_byte(uno_rig: AvrSim) -> None:
    cfg = Config(boards=[BoardSpec(uno_rig.url, timeout=2.0, uart_baud=115200)])
    with Daemon(cfg) as d:
        assert d.wait_until_up(20), d.status()
        before = _damage(d)  # (a frame the port was opened in the middle of: junk)
        with _stopped(_pty_thread(uno_rig)):  # (the board sends some 1.5 kB/s: < 1 s to fill)
            assert wait_for(lambda: _uart(uno_rig)["held"] + _uart(uno_rig)["dropped"] > 0, 20)
        counts = _uart(uno_rig)
        assert counts["dropped"] == 0, counts
        frames = d.status()[0]["frames"]
        assert wait_for(lambda: d.status()[0]["frames"] > frames + 20, 20)  # (all read since)
        assert _damage(d) == before
        s = d.status()[0]
        assert s["stale_links"] == 0 and s["connects"] == 1, s
