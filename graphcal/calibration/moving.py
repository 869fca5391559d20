"""Pairs seen on moving objects (traffic, pedestrians), and their rejection.

A pair (p, m) stands for one surface seen by two fibres. When the surface moved between the two
acquisitions, its residual r = n_p . (p - m) [m] carries the motion along the normal, n . v (t_p - t_m),
which no calibration can explain. A static surface's residual at the current estimate is the
calibration's remaining error (the same for the pairs of a fibre pair over similar geometry) plus noise.
So a pair is rejected when both hold:

- its residual departs from the median residual of its fibre pair (i, j) by more than `sigmas` robust
  sigmas of that fibre pair (1.4826 x the median absolute deviation, at least MOVING_FLOOR_M): the
  calibration's error common to the fibre pair is not taken for motion;
- |t_p - t_m| [s] is long enough for an object at `speed_m_s` [m/s] to have moved that far: returns
  acquired together (a surface seen by two fibres of the same firing) cannot disagree by motion.

Far from the solution the fibre pairs' residuals are spread, their sigmas wide, and little is rejected;
near it, the pairs on moving objects stand out.
"""

from __future__ import annotations

import numpy as np

from graphcal.calibration.association import Correspondences

MOVING_FLOOR_M = 0.002  # the least robust sigma of a fibre pair's residuals [m]: a noise-free simulation's are ~0
MAD_TO_SIGMA = 1.4826


def moving_pairs(pairs: Correspondences, points_m: np.ndarray, fibre: np.ndarray, time_s: np.ndarray,
                 sigmas: float, speed_m_s: float) -> np.ndarray:
    """(len(pairs),) bool: the pairs to reject as seen on a moving object (module docstring), from the points
    [m, world frame] at the current estimate, each return's fibre and acquisition time [s]."""
    p, m = pairs.index_p, pairs.index_m
    residual = np.einsum("ni,ni->n", pairs.normal, points_m[p] - points_m[m])
    group = fibre[p].astype(np.int64) * (int(fibre.max(initial=0)) + 1) + fibre[m]
    order = np.argsort(group, kind="stable")
    starts = np.flatnonzero(np.r_[True, np.diff(group[order]) != 0])
    departure = np.zeros(len(pairs))
    for start, stop in zip(starts, np.r_[starts[1:], len(order)]):
        rows = order[start:stop]
        centred = residual[rows] - np.median(residual[rows])
        sigma = max(MAD_TO_SIGMA * float(np.median(np.abs(centred))), MOVING_FLOOR_M)
        departure[rows] = np.abs(centred) / sigma
    apart_s = np.abs(time_s[p] - time_s[m])
    return (departure > sigmas) & (speed_m_s * apart_s > np.abs(residual))


def without_moving(pairs: Correspondences, points_m: np.ndarray, fibre: np.ndarray, time_s: np.ndarray,
                   sigmas: float | None, speed_m_s: float) -> Correspondences:
    """The pairs but those moving_pairs rejects (all of them with sigmas None)."""
    if sigmas is None or not len(pairs):
        return pairs
    return pairs.take(~moving_pairs(pairs, points_m, fibre, time_s, sigmas, speed_m_s))
