"""The estimated error's calibration against a known clock: one helper for the benchmarks that
measure it (``bench_timesync.py``, ``replay_timesync.py``)."""

from __future__ import annotations

import numpy as np


def est_stats(err_us: np.ndarray, est_us: np.ndarray) -> dict[str, float]:
    """How well the estimated error is calibrated: its median, its median over the median
    |error| (the issue's 1x..3x), and the share of samples with |error| <= 2 x estimate."""
    return {
        "est_p50": float(np.median(est_us)),
        "est_ratio": float(np.median(est_us) / max(np.median(err_us), 1e-9)),
        "in_2est": float(np.mean(err_us <= 2 * est_us)) * 100,
    }
