"""Bounded statistics for runs of any length: log-bin histograms, running moments, a ring of recent values.

A service runs for days: nothing here grows with the run. ``LogHistogram`` is HdrHistogram's
idea (fixed bins whose width is a fixed fraction of their value, so every percentile is known
to a stated relative resolution) on numpy: values arrive in blocks (the loop's ring when it
wraps), and one ``np.searchsorted`` plus ``np.bincount`` per block costs microseconds per
thousand values, where a per-value Python ``record`` (the ``hdrh`` package) would cost the loop
thread a few microseconds every cycle. numpy is already a dependency; a t-digest package
(``tdigest``, ``pytdigest``) would add one for a less explicit error bound.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


class LogHistogram:
    """Counts of non-negative values in fixed bins: [0, lowest), then bins each ``1 + resolution`` wider.

    A percentile is reported as the upper edge of the bin holding it, capped at the largest value
    seen: never below the true value, at most ``resolution`` (relative) or ``lowest`` (absolute)
    above it. Values below ``lowest`` (negative ones too) count in the first bin, values above
    ``highest`` in the last; the exact minimum and maximum are kept beside the bins.
    """

    def __init__(self, lowest: float, highest: float, resolution: float = 0.01) -> None:
        if not (lowest > 0 and highest > lowest):
            raise ValueError(
                f"LogHistogram: need 0 < lowest < highest, got lowest={lowest}, highest={highest}"
            )
        if not 0 < resolution < 1:
            raise ValueError(f"LogHistogram: resolution = {resolution}: must be in (0, 1)")
        self.lowest = lowest
        self.resolution = resolution
        n = math.ceil(math.log(highest / lowest) / math.log1p(resolution))
        # edges[i] is the lower edge of bin i; bin 0 is [0, lowest), the last bin is open above
        self.edges = np.concatenate(([0.0], lowest * (1.0 + resolution) ** np.arange(n + 1)))
        self.counts = np.zeros(self.edges.size, dtype=np.int64)
        self.count = 0
        self.total = 0.0
        self.min = math.inf
        self.max = -math.inf

    def add(self, values: np.ndarray) -> None:
        v = np.asarray(values, dtype=float)
        if v.size == 0:
            return
        idx = np.searchsorted(self.edges, v, side="right") - 1
        self.counts += np.bincount(np.clip(idx, 0, self.edges.size - 1), minlength=self.edges.size)
        self.count += int(v.size)
        self.total += float(v.sum())
        self.min = min(self.min, float(v.min()))
        self.max = max(self.max, float(v.max()))

    def percentile(self, q: float) -> float:
        """The ``q``-th percentile (0..100) to the histogram's resolution; 0.0 when empty."""
        if self.count == 0:
            return 0.0
        rank = max(1, math.ceil(q / 100.0 * self.count))
        i = int(np.searchsorted(np.cumsum(self.counts), rank))
        upper = float(self.edges[i + 1]) if i + 1 < self.edges.size else self.max
        return min(upper, self.max)

    @property
    def mean(self) -> float:
        return self.total / self.count if self.count else 0.0


@dataclass
class RunningMoments:
    """Count, root mean square and maximum of a stream of values, in constant memory."""

    count: int = 0
    sum_squares: float = 0.0
    max: float = -math.inf

    def add(self, value: float) -> None:
        self.count += 1
        self.sum_squares += value * value
        self.max = max(self.max, value)

    @property
    def rms(self) -> float | None:
        return math.sqrt(self.sum_squares / self.count) if self.count else None

    @property
    def maximum(self) -> float | None:
        return self.max if self.count else None


@dataclass
class FloatRing:
    """The last ``capacity`` floats of a stream (oldest first from ``values()``)."""

    capacity: int
    _buf: np.ndarray = field(init=False)
    _n: int = field(init=False, default=0)

    def __post_init__(self) -> None:
        if self.capacity < 1:
            raise ValueError(f"FloatRing: capacity = {self.capacity}: must be >= 1")
        self._buf = np.zeros(self.capacity)

    def append(self, value: float) -> None:
        self._buf[self._n % self.capacity] = value
        self._n += 1

    def __len__(self) -> int:
        return min(self._n, self.capacity)

    @property
    def appended(self) -> int:
        """Values ever appended (older ones than the last ``capacity`` are gone)."""
        return self._n

    def values(self) -> np.ndarray:
        if self._n <= self.capacity:
            return self._buf[: self._n].copy()
        i = self._n % self.capacity
        return np.concatenate((self._buf[i:], self._buf[:i]))
