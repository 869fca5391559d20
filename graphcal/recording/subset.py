"""Seeded subsets of a recording's returns (points.parquet, in time order): a random draw over the whole drive,
or, for a drive too long for its budget at a stated density, a random draw inside spans of time spread evenly
along it, so that the returns used are as dense along the drive as on a short one."""

from __future__ import annotations

import numpy as np

from graphcal.recording.points import PointTable

MIN_SPAN_S = 16.0  # a span lasts at least this [s]: the drives the density was measured on (diagnose)


def spread_spans_s(first_s: float, last_s: float, total_s: float, min_span_s: float = MIN_SPAN_S) -> np.ndarray:
    """Spans [s] (k, 2) of total_s in all, each at least min_span_s (all of total_s when shorter), their centres
    spread evenly over [first_s, last_s]; the whole drive as one span when total_s covers it."""
    if total_s >= last_s - first_s:
        return np.array([[first_s, last_s]])
    count = max(1, int(total_s // min_span_s))
    length_s = total_s / count
    centres_s = first_s + (np.arange(count) + 0.5) * (last_s - first_s) / count
    return np.c_[centres_s - length_s / 2, centres_s + length_s / 2]


def rows_before(points: PointTable, times_s: np.ndarray) -> np.ndarray:
    """For each time [s], the number of returns stamped before it (the first row at or after it), read batch by
    batch (points.parquet is in time order)."""
    counts = np.zeros(len(times_s), np.int64)
    for batch in points.iter_batches(["time"]):
        counts += np.searchsorted(batch["time"], times_s, side="left")
    return counts


def subset_rows(points: PointTable, max_points: int | None, rng: np.random.Generator,
                points_per_s: float | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """(rows, spans): max_points rows drawn at random (sorted; every row when there are no more) and the spans
    [s] (k, 2) they were drawn in: over the whole drive (spans None) when points_per_s is None or the whole
    drive at points_per_s returns a second holds no more than max_points, else in the spans that hold
    max_points at that density (spread_spans_s)."""
    n_rows = len(points)
    if max_points is None or n_rows <= max_points:
        return np.arange(n_rows), None
    spans_s = None
    if points_per_s is not None:
        first_s, last_s = points.time_span_s()
        spans_s = spread_spans_s(first_s, last_s, max_points / points_per_s)
        spans_s = None if spans_s[0, 0] <= first_s and spans_s[-1, 1] >= last_s else spans_s
    if spans_s is None:
        return np.sort(rng.choice(n_rows, max_points, replace=False)), None
    bounds = rows_before(points, spans_s.ravel()).reshape(-1, 2)
    lengths = bounds[:, 1] - bounds[:, 0]
    drawn = np.sort(rng.choice(lengths.sum(), min(max_points, int(lengths.sum())), replace=False))
    span = np.searchsorted(np.cumsum(lengths), drawn, side="right")
    return drawn - np.r_[0, np.cumsum(lengths)][span] + bounds[span, 0], spans_s
