"""worldfeed.steps_at (the world's encoder edges into the simulated board, virtual/world/) in real
MicroPython, 32-bit like a board's: a run of edges over a span longer than a second (a tick that
caught up with a late runtime) took span * k, beyond a small integer (2^30) once span * n passed
it, and every such edge put a long integer in the board's heap; it now adds, in small integers
throughout.  The heap figure is MicroPython's own (gc.mem_alloc, collections off)."""

from __future__ import annotations

from typing import Any

import pytest

from .helpers import simworld_probe

WRAP = 1 << 30


def steps_at(*cases: tuple[int, int, int]) -> list[dict[str, Any]]:
    return simworld_probe("worldfeed_heap", cases)


@pytest.mark.micropython
@pytest.mark.slow
def test_a_run_of_edges_over_seconds_puts_nothing_in_the_boards_heap() -> None:
    n = 2000  # (the rover's two encoders' edges in a second's catch-up, and more)
    cases = [(n, 1000, 100_000), (n, 1000, 2_500_000), (n, 1000, 600_000_000),
             (n, WRAP - 1_000_000, 2_500_000), (3, 5, 7), (1, 5, 2_500_000)]  # fmt: skip
    got = steps_at(*cases)
    assert len(got) == len(cases)
    for (count, t0, span), g in zip(cases, got, strict=True):
        seen = g["seen"]
        assert g["grew"] == 0, (count, span, g)  # (no long integer, no object a edge)
        assert seen[0] == count
        assert seen[1] == t0  # (each edge's handler reads its time: the first at t0 ...)
        if count > 1:
            assert seen[2] == (t0 + span // (count - 1)) % WRAP
            assert seen[3] == (t0 + span) % WRAP  # (... the last at t0 + span, wrapped)
