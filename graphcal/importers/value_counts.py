"""The exact median of values that come in chunks, in memory bounded by how many distinct values there are
(packet spacings in whole microseconds, packet spin rates: a few dozen in a capture of any length)."""

from __future__ import annotations

import numpy as np


class ValueCounts:
    """How often each value came; its median equals np.median of all the values (NaN for none)."""

    def __init__(self):
        self._counts: dict[float, int] = {}

    def add(self, values: np.ndarray) -> None:
        found, counts = np.unique(np.asarray(values, dtype=np.float64), return_counts=True)
        for value, count in zip(found.tolist(), counts.tolist()):
            self._counts[value] = self._counts.get(value, 0) + count

    def __len__(self) -> int:
        return sum(self._counts.values())

    def median(self) -> float:
        """The middle value, or the mean of the two middle ones for an even count (as np.median)."""
        n = len(self)
        if not n:
            return float("nan")
        values = np.array(sorted(self._counts))
        ends = np.cumsum([self._counts[value] for value in values])
        lower, upper = values[np.searchsorted(ends, [(n - 1) // 2 + 1, n // 2 + 1])]
        return float(lower) if n % 2 else float(np.mean([lower, upper]))
