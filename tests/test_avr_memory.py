"""The AVR firmware's stack low point (firmware/avr/src/memory.c): painted at boot, counted by
the board itself (a2jMemory), and the same figure the rig finds from outside as the lowest
stack pointer simavr saw (rig_sim.c "stack"): real AVR machine code in simavr."""

from __future__ import annotations

import struct
import subprocess
import time
from pathlib import Path

import pytest

from missing_link.daemon.session.board_memory import parse_memory
from missing_link.host.board import Board
from missing_link.transport import open_transport

from .helpers import AvrSim

pytestmark = [pytest.mark.avr, pytest.mark.slow]
H0 = 1_795_000_000_000_000_000


def _symbol(elf: Path, name: str) -> int:
    nm = subprocess.run(["avr-nm", str(elf)], capture_output=True, text=True, check=True).stdout
    return next(int(x.split()[0], 16) & 0xFFFF for x in nm.splitlines() if x.endswith(" " + name))


def test_the_boards_stack_low_point_is_the_one_the_rig_sees(
    avr_build: Path, uno_rig: AvrSim
) -> None:
    elf = avr_build / "uno_rig" / "firmware.elf"
    end = _symbol(elf, "_end")
    board = Board(open_transport(uno_rig.url), timeout=5.0)
    try:
        board.handshake()
        board.config()  # (deep calls: the configuration, a map, aligned sampling, a timed pulse)
        b0 = board.clock_exchange(5.0).t3
        board.call_ok("a2jHostMap", struct.pack("<Qqi", b0, H0, 0))
        board.configure({"dist_ir.aligned": True})
        at = H0 + (board.clock_exchange(5.0).t3 + 50_000 - b0) * 1000
        board.call_ok("a2jAt", struct.pack("<qB", at, board.index["a2j_trigger"]) + b"\x2c\x01")
        uno_rig.ctl("enc 100")
        time.sleep(0.3)
        board.call_ok("a2jMemory")  # (its own frames are as deep as the next one's)
        first = parse_memory(board.call_ok("a2jMemory"))
        low = int(uno_rig.ctl("stack").split()[1], 16)
        again = parse_memory(board.call_ok("a2jMemory"))
    finally:
        board.close()
    assert first.problem == "" and first.ram_size == 2048 and first.ram_static is not None
    assert first.ram_static == end - 0x100  # (.data and .bss: RAM starts at 0x100)
    assert first.stack_size == 2048 + 0x100 - end
    # the rig's lowest stack pointer: the deepest byte written is the one above it
    outside = low + 1 - end
    assert first.stack_free_low == outside, (first, low, end)
    assert again.stack_free_low is not None and again.stack_free_low <= outside
    assert outside >= 64  # (the stack never came near static RAM)
