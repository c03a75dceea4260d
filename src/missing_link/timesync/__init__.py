"""Clock synchronisation: every board timestamp in host time, monotonic, with an error bound.

- :mod:`.estimator`: offset and skew from ``a2jClock`` exchanges, with a hard band (pure);
- :mod:`.published`: the continuous, strictly increasing map samples are stamped with (pure);
- :mod:`.sync`: one board's state machine - estimator, map, probe schedule (pure);
- :mod:`.sim`: clock and link models and the anchor methods, for benchmarks and tests (pure).
"""

from .estimator import AddResult, ClockEstimator, Estimate, Exchange
from .published import PublishedMap
from .sync import NOT_SYNCED, OUTLIER, STEP, ClockSync, Mapped, SyncOptions

__all__ = [
    "NOT_SYNCED",
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
