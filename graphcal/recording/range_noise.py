"""The range noise of a head, measured from its own returns (no target, no truth)."""

from __future__ import annotations

import numpy as np

# fourth difference of five consecutive ranges: cancels any cubic (a smooth surface's range along a
# fibre's sweep), unit gain on white noise
FOURTH_DIFFERENCE = np.array([1.0, -4.0, 6.0, -4.0, 1.0]) / np.sqrt(70.0)
SAMPLE_ROWS = 1_000_000  # the first rows of a recording say as much as all of them
MIN_DIFFERENCES = 100
# range noise [m] from which a head is treated as noisy (docs/reference/math.md "Which m"): m chosen by stand-ins, pairs
# whitened by the noise along their lines of sight, features from voxels. Without noise the nearest return
# pairs better (sim2_street noise-free, full size: d_elevation 5.3e-4 / 8.0e-4 deg, Hz 0.0113 cm against
# 7.9e-4 / 1.0e-3 deg, 0.0153 / 0.0145 cm with stand-ins, seeds 0 / 1), and the nearest's own bias grows with
# the noise (1 cm: -2.4 mm a pair). Real heads: 5 mm and more (monterey's HDL-32E 7.4 mm); a noise-free
# simulation decimated to every 20th firing measures 0.7 mm (its surfaces are not cubic over five firings 3.3
# deg apart)
NOISY_ABOVE_M = 1e-3


def noisy(range_noise_m: float) -> bool:
    """Whether a head with this range noise [m] is treated as noisy (NaN, unknown: it is)."""
    return not range_noise_m < NOISY_ABOVE_M


def measured_range_noise_m(fibre: np.ndarray, range_m: np.ndarray) -> float:
    """Robust 1-sigma [m] of the range noise of the returns (rows in firing order: time order): the
    median absolute fourth difference of each fibre's consecutive ranges, scaled to a Gaussian's
    sigma (x 1.4826). Over five firings (a fraction of a degree of azimuth) a surface's range is a
    cubic to far below a millimetre; edges and gaps are the outliers the median ignores. Measured:
    sim2_street without noise 4e-7 m (float32 ranges), with 1 mm / 1 cm of noise 1.1 / 10.7 mm;
    the real HDL-32E of monterey 7.4 mm. NaN when fewer than MIN_DIFFERENCES differences exist."""
    fibre, range_m = np.asarray(fibre)[:SAMPLE_ROWS], np.asarray(range_m, dtype=np.float64)[:SAMPLE_ROWS]
    width = len(FOURTH_DIFFERENCE)
    if len(range_m) < width:
        return float("nan")
    order = np.argsort(fibre, kind="stable")
    window = np.lib.stride_tricks.sliding_window_view(range_m[order], width)
    one_fibre = fibre[order][:len(window)] == fibre[order][width - 1:]  # the five ranges are one fibre's
    differences = window[one_fibre] @ FOURTH_DIFFERENCE
    if len(differences) < MIN_DIFFERENCES:
        return float("nan")
    return float(1.4826 * np.median(np.abs(differences)))
