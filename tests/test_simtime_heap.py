"""simtime (the simulated board's clock under --fast, virtual/world/) in real MicroPython, 32-bit
like a board's: ticks_diff computed with the clock's period, 2^30, one past the largest small
integer, so every call put a long integer or two (32 or 64 B) in the simulated board's heap,
where a board's own time.ticks_diff allocates nothing; the simulated I2C and UART parts and the
link (board/link.py) call it on every step.  It now computes in small integers throughout.  The
answers are a board's: the difference of two tick counts taken modulo 2^30 into
[-2^29, 2^29).  The heap figure is MicroPython's own (gc.mem_alloc, collections off)."""

from __future__ import annotations

from typing import Any

import pytest

from .helpers import simworld_probe

WRAP = 1 << 30
HALF = WRAP >> 1


def board_ticks_diff(a: int, b: int) -> int:
    """MicroPython's time.ticks_diff (extmod/modtime.c), for a period of 2^30."""
    return ((a - b + HALF) & (WRAP - 1)) - HALF


def calls(*cases: tuple[int, int, int]) -> list[dict[str, Any]]:
    return simworld_probe("simtime_heap", cases)


@pytest.mark.micropython
@pytest.mark.slow
def test_ticks_diff_across_the_wrap_puts_nothing_in_the_boards_heap() -> None:
    n = 3000
    pairs = [(5, 3), (3, 5), (WRAP - 1, 0), (0, WRAP - 1), (10, WRAP - 10), (WRAP - 10, 10),
             (HALF, 0), (0, HALF), (HALF - 1, 0), (0, HALF - 1), (HALF + 1, 0), (7, 7),
             (WRAP - 1, WRAP - 1), (123_456_789, 987_654_321)]  # fmt: skip
    got = calls(*[(a, b, n) for a, b in pairs])
    assert len(got) == len(pairs)
    for (a, b), g in zip(pairs, got, strict=True):
        assert g["grew"] == 0, (a, b, g)  # (no long integer a call)
        assert g["diff"] == board_ticks_diff(a, b), (a, b, g)
        # (b moved on by the difference is a again; ticks_add refuses -2^29, as the port's)
        assert g["add"] == (None if g["diff"] == -HALF else a), (a, b, g)
