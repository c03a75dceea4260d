"""Clock synchronisation: every board timestamp in host time, monotonic, with an error bound.

- :mod:`.exchange`: one ``a2jClock`` round trip (pure, light: what a board hands the sync);
- :mod:`.estimator`: offset and skew from exchanges, with a hard band (pure; numpy);
- :mod:`.published`: the continuous, strictly increasing map samples are stamped with (pure);
- :mod:`.sync`: one board's state machine - estimator, map, probe schedule (pure).

The clock and link simulations (benchmarks, tests) live in :mod:`missing_link.virtual.syncsim`.
Names are loaded on first use, so ``from missing_link.timesync.exchange import Exchange`` does
not import numpy.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..lazy import lazy_names

if TYPE_CHECKING:
    from .estimator import AddResult, ClockEstimator, Estimate
    from .exchange import Exchange
    from .published import PublishedMap
    from .sync import NOT_SYNCED, OFF_GRID, OUTLIER, STEP, ClockSync, Mapped, SyncOptions

_WHERE = {
    "AddResult": "estimator",
    "ClockEstimator": "estimator",
    "Estimate": "estimator",
    "Exchange": "exchange",
    "PublishedMap": "published",
    "NOT_SYNCED": "sync",
    "OFF_GRID": "sync",
    "OUTLIER": "sync",
    "STEP": "sync",
    "ClockSync": "sync",
    "Mapped": "sync",
    "SyncOptions": "sync",
}

__all__ = [
    "NOT_SYNCED",
    "OFF_GRID",
    "OUTLIER",
    "STEP",
    "AddResult",
    "ClockEstimator",
    "ClockSync",
    "Estimate",
    "Exchange",
    "Mapped",
    "PublishedMap",
    "SyncOptions",
]


__getattr__ = lazy_names(__name__, _WHERE, globals())
