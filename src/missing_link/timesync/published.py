"""The published map: what samples are stamped with.  Continuous, strictly increasing.  Pure code.

Theory of operation
-------------------
The estimator's best line moves a little with every exchange; stamping samples with it directly
would make host times jump (and sometimes go backwards).  The published map is instead a chain
of line segments in board time, each starting where the previous one ends (continuity), with a
rate within ``max_slew`` of the estimator's (so it is always strictly increasing):

    steer(estimate):  anchor a new segment at the newest board time already mapped (or the
                      estimate's reference, whichever is later), at the current published value;
                      it slews at ``-error / tau`` (at most ``max_slew``) until the error is gone,
                      then a second segment continues at the estimate's rate.

A new steer while a slew is under way keeps that slew's end: the map reaches the estimate
``tau`` after the error appeared however often it is steered (longer only when the slew limit
binds), never overshoots even if no further exchange comes, and never steps.  Only
``start()`` steps: at the first estimate and after a board reset; the caller flags it.  Segments
are anchored at or after every board time already mapped, so a value once published is never
contradicted by a later segment.  A short history of segments maps samples that arrive late.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from collections.abc import Sequence

from .estimator import Estimate

MAX_SLEW = 500e-6  # relative rate correction (500 ppm, like adjtime)


class PublishedMap:
    def __init__(self, *, max_slew: float = MAX_SLEW, tau_s: float = 2.0, history: int = 256):
        self.max_slew = max_slew
        self.tau_us = tau_s * 1e6
        self.history = history
        self._anchors: list[int] = []  # board µs
        self._segs: list[tuple[int, float, float]] = []  # (board µs, host ns, ns per µs)
        self.newest_mapped: int | None = None
        self._floor = 0
        self._slew_end: float = 0
        self.steps = 0
        #: the segment the sample path used last, as (from, until, b0, h0, rate): it asks for the
        #: same one for seconds; None once the segments change
        self.hot: tuple[float, float, int, float, float] | None = None

    @property
    def started(self) -> bool:
        return bool(self._segs)

    def start(self, est: Estimate) -> None:
        """Step to the estimate (start, or after a reset).  Before anything was mapped it may
        be called again with every better estimate: a step nobody saw costs nothing."""
        if not self._segs or self.newest_mapped is not None:
            self.steps += 1
        self._segs = [(est.b_ref, est.h_ref, est.rate)]
        self._anchors = [est.b_ref]
        self.hot = None
        self._floor = est.b_ref
        self._slew_end = est.b_ref
        self.newest_mapped = None

    def steer(self, est: Estimate) -> float:
        """Bend the map towards ``est``; returns the published-minus-estimate error (ns)."""
        if not self._segs:
            self.start(est)
            return 0.0
        # Anchor no earlier than the last steer or any board time already mapped; the segment
        # that ends the previous slew may lie beyond that, in the future: it is replaced.
        b = max(est.b_ref, self._floor)
        if self.newest_mapped is not None and self.newest_mapped > b:
            b = self.newest_mapped
        self._floor = b
        self.hot = None
        h = self.at(b)
        err = h - est.host_at(b)
        # Segments anchored after b lie in the future (nothing was mapped with them): replace.
        while len(self._anchors) > 1 and self._anchors[-1] > b:
            self._anchors.pop()
            self._segs.pop()
        if self._anchors[-1] >= b:
            self._anchors.pop()
            self._segs.pop()
        # Remove err by the end of the slew already under way (a fresh one: within tau), so
        # the map reaches the estimate in tau however often it is steered; slower only when
        # the slew limit binds.
        remaining = self._slew_end - b if self._slew_end > b else self.tau_us
        dur = max(remaining, 0.05 * self.tau_us, abs(err) / (self.max_slew * est.rate))
        self._slew_end = b + dur
        self._segs.append((b, h, est.rate - err / dur))
        self._anchors.append(b)
        end = b + max(1, round(dur))
        self._segs.append((end, h + (end - b) * (est.rate - err / dur), est.rate))
        self._anchors.append(end)
        if len(self._segs) > self.history:
            del self._segs[:2]
            del self._anchors[:2]
        return err

    def at(self, board_us: int) -> float:
        """Published host ns for a board time (no bookkeeping)."""
        segs = self._segs
        b0, h0, rate = segs[-1]
        if board_us < b0:
            i = bisect_right(self._anchors, board_us) - 1
            b0, h0, rate = segs[max(i, 0)]
        return h0 + (board_us - b0) * rate

    def segment(self, board_us: int) -> tuple[float, float, int, float, float]:
        """The segment that maps ``board_us``, as (from, until, b0, h0, rate): it maps every
        board time in [from, until) as ``h0 + (b - b0) * rate`` (the first one also maps times
        before it, the last one times after it).  The sample path asks for the same one for
        seconds: the last one found is kept (``hot``) until the segments change."""
        hot = self.hot
        if hot is not None and hot[0] <= board_us < hot[1]:
            return hot
        anchors = self._anchors
        i = max(bisect_right(anchors, board_us) - 1, 0)
        start = anchors[i] if i > 0 else -math.inf
        until = anchors[i + 1] if i + 1 < len(anchors) else math.inf
        b0, h0, rate = self._segs[i]
        self.hot = hot = (start, until, b0, h0, rate)
        return hot

    def at_many(
        self,
        stamps: Sequence[int],
        lo: int,
        seg: tuple[float, float, int, float, float],
        offset_ns: int = 0,
    ) -> list[int]:
        """Published host ns (rounded, plus ``offset_ns``) for the stamps of one update: ``lo``
        their smallest, ``seg`` the segment of their largest (``segment``).  One segment for all
        when they share it (almost always: they were taken within one sample period), else
        ``at`` per stamp."""
        start, _, b0, h0, rate = seg
        if lo < start:  # the update spans an anchor
            return [round(self.at(b)) + offset_ns for b in stamps]
        return [round(h0 + (b - b0) * rate) + offset_ns for b in stamps]

    def map(self, board_us: int) -> float:
        """Published host ns for a sample's board time; remembers the newest one mapped."""
        if self.newest_mapped is None or board_us > self.newest_mapped:
            self.newest_mapped = board_us
        return self.at(board_us)

    @property
    def rate(self) -> float:
        return self._segs[-1][2] if self._segs else 1000.0
