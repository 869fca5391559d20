"""The drift of a GNSS-aided INS that InsErrors switches on: random walks, a slow bias and GNSS-like jumps.

Times in s; position errors along the local frame's axes (x east, y north, z up) [m]; the heading
error about z [deg]. Only the switched-on terms draw from the generator, so that a scenario without
drift draws (and records) exactly what it did before these terms existed.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import lfilter

from graphcal.simulation.scenario import InsErrors

# the slow bias is drawn on a regular grid of this many steps per correlation time, then interpolated
_BIAS_STEPS_PER_CORRELATION = 50


def ins_drift(time_s: np.ndarray, errors: InsErrors, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(position error (N,3) [m], heading error (N,) [deg]) at the poses' increasing times time_s [s]."""
    dt_s = np.diff(time_s)
    position_m = np.zeros((len(time_s), 3))
    heading_deg = np.zeros(len(time_s))
    if errors.position_walk_m_sqrt_s > 0:
        position_m += random_walk(dt_s, errors.position_walk_m_sqrt_s, 3, rng)
    if errors.heading_walk_deg_sqrt_s > 0:
        heading_deg += random_walk(dt_s, errors.heading_walk_deg_sqrt_s, 1, rng)[:, 0]
    if errors.position_bias_m > 0:
        position_m += slow_bias(time_s, errors.position_bias_m, errors.bias_correlation_s, rng)
    if errors.jump_rate_hz > 0 and errors.jump_m > 0:
        position_m += jumps(time_s, errors.jump_rate_hz, errors.jump_m, rng)
    return position_m, heading_deg


def random_walk(dt_s: np.ndarray, intensity: float, n_axes: int, rng: np.random.Generator) -> np.ndarray:
    """(len(dt_s) + 1, n_axes) random walk starting at 0: independent Gaussian steps of sigma
    intensity x sqrt(dt) (intensity in units per sqrt(s))."""
    steps = rng.normal(0.0, 1.0, (len(dt_s), n_axes)) * (intensity * np.sqrt(dt_s))[:, None]
    return np.vstack([np.zeros((1, n_axes)), np.cumsum(steps, axis=0)])


def slow_bias(time_s: np.ndarray, sigma_m: float, correlation_s: float, rng: np.random.Generator) -> np.ndarray:
    """(N,3) first-order Gauss-Markov bias of stationary sigma_m per axis and correlation time correlation_s,
    exact on a regular grid of correlation_s / 50 and interpolated linearly at time_s."""
    step_s = correlation_s / _BIAS_STEPS_PER_CORRELATION
    grid_s = time_s[0] + step_s * np.arange(int(np.ceil((time_s[-1] - time_s[0]) / step_s)) + 1)
    phi = np.exp(-step_s / correlation_s)
    white = rng.normal(0.0, sigma_m, (len(grid_s), 3))
    # b[0] = w[0] (stationary start); b[k] = phi b[k-1] + sqrt(1 - phi^2) w[k]
    bias, _ = lfilter([np.sqrt(1.0 - phi * phi)], [1.0, -phi], white[1:], axis=0, zi=phi * white[:1])
    bias = np.vstack([white[:1], bias])
    return np.column_stack([np.interp(time_s, grid_s, bias[:, k]) for k in range(3)])


def jumps(time_s: np.ndarray, rate_hz: float, sigma_m: float, rng: np.random.Generator) -> np.ndarray:
    """(N,3) sum of the position steps (sigma_m per axis) of GNSS-like jumps at Poisson times of mean rate
    rate_hz over [time_s[0], time_s[-1]]: each step holds from its time on."""
    n_jumps = rng.poisson(rate_hz * (time_s[-1] - time_s[0]))
    jump_times = np.sort(rng.uniform(time_s[0], time_s[-1], n_jumps))
    offsets = np.vstack([np.zeros((1, 3)), np.cumsum(rng.normal(0.0, sigma_m, (n_jumps, 3)), axis=0)])
    return offsets[np.searchsorted(jump_times, time_s, side="right")]
