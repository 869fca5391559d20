"""The range noise of a head, measured from its own returns (no target, no truth)."""

from __future__ import annotations

import numpy as np

# fourth difference of five evenly spaced samples: cancels any cubic, unit gain on white noise (the trajectory's poses:
# trajectory_noise.py). A fibre's five consecutive ranges combine into its generalisation, the fourth divided
# difference in azimuth at unit gain, which cancels any cubic in azimuth (a smooth surface's range along the sweep)
# whatever the spacing of the firings, and is this one where they are evenly spaced
FOURTH_DIFFERENCE = np.array([1.0, -4.0, 6.0, -4.0, 1.0]) / np.sqrt(70.0)
WIDTH = len(FOURTH_DIFFERENCE)
SAMPLE_ROWS = 1_000_000  # the first rows of a recording say as much as all of them
MIN_DIFFERENCES = 100
# range noise [m] from which a head is treated as noisy (docs/reference/math.md "Which m"): m chosen by stand-ins, pairs
# whitened by the noise along their lines of sight, features from voxels. Without noise the nearest return
# pairs better (sim2_street noise-free, full size: d_elevation 5.3e-4 / 8.0e-4 deg, Hz 0.0113 cm against
# 7.9e-4 / 1.0e-3 deg, 0.0153 / 0.0145 cm with stand-ins, seeds 0 / 1), and the nearest's own bias grows with
# the noise (1 cm: -2.4 mm a pair). Real heads: 5 mm and more (monterey's HDL-32E 7.2 mm); a noise-free
# simulation decimated to every 20th firing measures 0.7 mm (its surfaces are not cubic over five firings 3.3
# deg apart)
NOISY_ABOVE_M = 1e-3


def noisy(range_noise_m: float) -> bool:
    """Whether a head with this range noise [m] is treated as noisy (NaN, unknown: it is)."""
    return not range_noise_m < NOISY_ABOVE_M


def measured_range_noise_m(fibre: np.ndarray, range_m: np.ndarray, azimuth_rad: np.ndarray) -> float:
    """Robust 1-sigma [m] of the range noise of the returns (rows in firing order: time order; azimuth: the encoder
    angle [rad]): the median absolute fourth divided difference in azimuth of each fibre's five consecutive ranges,
    at unit gain on white noise, scaled to a Gaussian's sigma (x 1.4826). Over five firings a surface's range is a
    cubic in azimuth to far below a millimetre; edges and gaps are the outliers the median ignores. The divided
    difference, unlike the plain fourth difference, holds where firings are dropped unevenly (a recording thinned
    to a fraction of its firing blocks; a 1 cm head in the foreign box street with 0.03 / 0.1 / 0.4 / all of its
    blocks kept at random: 1.82 / 1.27 / 1.08 / 1.04 cm, the plain difference 12.2 / 2.6 / 1.5 / 1.04 cm).
    Measured: sim2_street without noise 4e-7 m (float32 ranges), with 1 mm / 1 cm of noise 1.1 / 10.7 mm; the real
    HDL-32E of monterey 7.2 mm (7.4 by the plain difference). NaN when fewer than MIN_DIFFERENCES differences exist
    (five ranges at one azimuth, a dual return's, make none)."""
    fibre = np.asarray(fibre)[:SAMPLE_ROWS]
    range_m = np.asarray(range_m, dtype=np.float64)[:SAMPLE_ROWS]
    azimuth_rad = np.asarray(azimuth_rad, dtype=np.float64)[:SAMPLE_ROWS]
    if len(range_m) < WIDTH:
        return float("nan")
    order = np.argsort(fibre, kind="stable")
    windows = [np.lib.stride_tricks.sliding_window_view(values[order], WIDTH) for values in (range_m, azimuth_rad)]
    one_fibre = fibre[order][:len(windows[0])] == fibre[order][WIDTH - 1:]  # the five ranges are one fibre's
    ranges, azimuths = (window[one_fibre] for window in windows)
    apart = np.angle(np.exp(1j * (azimuths - azimuths[:, :1])))  # [rad] from the first firing, across the wrap
    weights = np.ones_like(apart)
    for k in range(WIDTH):
        for j in range(WIDTH):
            if j != k:
                weights[:, k] *= apart[:, k] - apart[:, j]
    with np.errstate(divide="ignore", invalid="ignore"):
        weights = 1.0 / weights
        differences = np.einsum("nk,nk->n", weights, ranges) / np.linalg.norm(weights, axis=1)
    differences = differences[np.isfinite(differences)]
    if len(differences) < MIN_DIFFERENCES:
        return float("nan")
    return float(1.4826 * np.median(np.abs(differences)))
