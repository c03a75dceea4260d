"""simtime.ticks_add (the simulated board's clock under --fast, virtual/world/) does what the
port's time.ticks_add does, both run in real MicroPython (the WebAssembly port, 32-bit like a
board's) on the same calls: t + delta wrapped at 2^30 while |delta| < 2^29, and past that an
OverflowError, "ticks interval overflow" (beyond a 32-bit word, "overflow converting long int
to machine word"), as extmod/modtime.c checks that ticks_diff could give the delta back.  It
wrapped any delta: firmware that asked for one would have run in the simulator and raised on a
board."""

from __future__ import annotations

import pytest

from .helpers import simworld_probe

TICKS = ["0", "5", "(1 << 30) - 1", "123456789"]
DELTAS = [
    "0", "1", "-1", "1000", "-1000",
    "(1 << 29) - 1", "1 << 29", "(1 << 29) + 1", "-(1 << 29) + 1", "-(1 << 29)", "-(1 << 29) - 1",
    "1 << 30", "-(1 << 30)", "(1 << 31) - 1", "1 << 31", "-(1 << 31)", "-(1 << 31) - 1",
    "1 << 40", "-(1 << 40)", "10 ** 30", "True", "1.5", "'1'",
]  # fmt: skip


@pytest.mark.micropython
@pytest.mark.slow
def test_ticks_add_is_the_ports() -> None:
    cases = [(t, d) for t in TICKS for d in DELTAS]
    got = simworld_probe("simtime_ticks_add", cases)
    assert len(got) == len(cases)
    for case, g in zip(cases, got, strict=True):
        assert g["sim"] == g["port"], case
    refused = {d for (_t, d), g in zip(cases, got, strict=True) if g["port"][0] != "="}
    # (the rule the port was seen to keep: what the comparison above covers)
    assert refused == {
        "1 << 29", "(1 << 29) + 1", "-(1 << 29)", "-(1 << 29) - 1", "1 << 30", "-(1 << 30)",
        "(1 << 31) - 1", "1 << 31", "-(1 << 31)", "-(1 << 31) - 1", "1 << 40", "-(1 << 40)",
        "10 ** 30", "1.5", "'1'",
    }  # fmt: skip


@pytest.mark.micropython
@pytest.mark.slow
def test_ticks_ms_and_time_go_on_past_the_wrap_of_ticks_us() -> None:
    """Derived from the µs counter, ticks_ms and time() restarted with it every 2^30 µs (17.9
    simulated minutes); a board's ticks_ms wraps at 2^30 ms (12.4 days) and time() never.  Now
    they count the time unwrapped, in small integers (nothing in the board's heap a read)."""
    cases = [(1, 1000), (11, 100_000_000), (30, 123_456_789), (200, 400_000_000)]
    got = simworld_probe("simtime_unwrapped", cases)
    assert len(got) == len(cases)
    for (steps, us), g in zip(cases, got, strict=True):
        total = steps * us + 1000 * 997  # (and the probe's own thousand steps)
        assert g["us"] == total % (1 << 30), (steps, us, g)
        assert (g["ms"], g["s"]) == (total // 1000 % (1 << 30), total // 10**6), (steps, us, g)
        assert g["grew"] == 0, (steps, us, g)
