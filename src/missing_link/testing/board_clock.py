"""A fake of a board's clock: the µs a board runtime reads (``BoardRuntime(clock=...)``,
``make_sim(name, clock=...)``), standing still until a test turns it."""

from __future__ import annotations


class FakeBoardClock:
    """A board's µs clock that a test turns: a runtime calls it for the time (as it calls
    board/clock.py's on a device); :meth:`advance` moves it.  It starts at ``start_us`` (1 s:
    0 means "unset" in some stamps).  ``us`` is the time now (a test may set it)."""

    def __init__(self, start_us: int = 1_000_000) -> None:
        self.us = start_us

    def __call__(self) -> int:
        return self.us

    def advance(self, us: int) -> int:
        """Move the clock ``us`` (>= 0) forward; the time then."""
        if us < 0:
            raise ValueError(f"a board's clock goes forward only: advance({us!r})")
        self.us += us
        return self.us

    def __repr__(self) -> str:
        return f"<FakeBoardClock at {self.us} us>"
