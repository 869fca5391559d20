"""Steps in a recorded trajectory's positions, found from its own poses (no truth).

A GNSS-aided INS that takes a GNSS fix into its solution moves its output position at once: the recorded
position steps between two samples by centimetres, a jump no vehicle makes in 10 ms (7 cm in 10 ms is 7 m/s
gained and lost in a sample). Trajectory corrections interpolated linearly between controls a second apart
cannot follow a step: the returns of that interval keep up to half of it. A control on each side of the step
(calibration/returns.py) lets the corrections step with the INS, and the step itself, measured here
(step_vectors_m), says by how much: the vehicle does not jump, so the INS's error steps by what its position does.

A step shows in the change of velocity at one sample against its neighbours: for the interval k between samples
k and k+1, jump_k = (v_k - (v_(k-1) + v_(k+1)) / 2) dt_k [m] (v the velocity over each interval) is the step
itself at k and minus half of it at k - 1 and k + 1; the vehicle's own acceleration a gives a dt^2 (3 m/s^2 over
10 ms: 0.3 mm; at most MAX_ACCELERATION_M_S2 dt^2, which bounds the jumps counted as steps from below: a
trajectory of 10 poses a second cannot tell a 5 cm step from a hard brake) and a random walk of the INS's error
(5 mm/sqrt(s): 0.6 mm) far less.

Under white noise a step is not one sample's jump (5 mm of noise a sample gives jumps of 11 mm RMS per axis): it is
the difference between what the samples on either side say at the boundary, a quadratic fitted to the
STEP_WINDOW samples before and one fitted to the STEP_WINDOW after, both taken at the boundary
(noisy_steps). The smoothing of the trajectory's white noise (trajectory_noise.py) runs on either side of those
steps apart, so that it keeps them; position_steps then finds them in the smoothed poses.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import maximum_filter1d

from graphcal.recording.poses import PoseTrack

STEP_TIMES_MEDIAN = 10.0  # a step's jump is at least this many times the median jump over the drive ...
MIN_STEP_M = 0.01  # ... and at least this [m]: a smaller step leaves at most half of it, within a 1 cm range noise
MAX_ACCELERATION_M_S2 = 10.0  # ... and above what a vehicle's acceleration (1 g) gives over the interval
STEP_WINDOW = 50  # samples of each side's quadratic under white noise (0.5 s at 100 Hz)
STEP_SIGMAS = 8.0  # a step under white noise stands this many of its own sigmas out (3 axes: chi, 3 dof)
SMOOTHED_END = 2.5  # a smoothing's error at an end (one side holds it) over its error within: 2.2-2.7 (24 drives)


def position_steps(poses: PoseTrack) -> np.ndarray:
    """(S, 2) times [s] of the two samples between which the recorded position steps (module docstring): the
    intervals whose jump is above STEP_TIMES_MEDIAN x the drive's median jump and MIN_STEP_M, and the largest of
    the three about it, and above MAX_ACCELERATION_M_S2 dt^2; none on a track of fewer than five poses."""
    time_s = poses.time
    if len(time_s) < 5:
        return np.zeros((0, 2))
    dt_s = np.diff(time_s)
    jump_m = np.linalg.norm(_jumps_m(poses), axis=1)
    threshold_m = max(STEP_TIMES_MEDIAN * float(np.median(jump_m)), MIN_STEP_M)
    padded = np.r_[0.0, jump_m, 0.0]
    peak = ((jump_m > np.maximum(threshold_m, MAX_ACCELERATION_M_S2 * dt_s[1:-1] ** 2))
            & (jump_m >= padded[:-2]) & (jump_m >= padded[2:]))
    interval = np.flatnonzero(peak) + 1  # jump_m[i] is the interval i + 1's
    return np.column_stack([time_s[interval], time_s[interval + 1]])


def step_vectors_m(poses: PoseTrack, steps_s: np.ndarray, smoothing_error_m: float = 0.0) -> tuple[np.ndarray, float]:
    """(S, 3) [m, world axes] what the recorded position steps by at each of steps_s ((S, 2) the times of the
    samples either side, position_steps): the interval's jump (module docstring), the vehicle's own motion taken
    out; and the 1-sigma [m] of each of its components: the drive's median jump over sqrt(3) (the jump of an
    interval without a step: the INS's random walk) and, on poses smoothed on either side of each step apart,
    the error of the two smoothings' ends (SMOOTHED_END x smoothing_error_m, the error smoothing leaves within
    the poses, per axis: trajectory_noise.smoothed_poses)."""
    if not len(steps_s):
        return np.zeros((0, 3)), 0.0
    jumps_m = _jumps_m(poses)
    interval = np.searchsorted(poses.time, steps_s[:, 0]) - 1  # jumps_m[i] is the interval i + 1's
    median_m = float(np.median(np.linalg.norm(jumps_m, axis=1))) / np.sqrt(3.0)
    return jumps_m[interval], float(np.sqrt(median_m ** 2 + 2.0 * (SMOOTHED_END * smoothing_error_m) ** 2))


def _jumps_m(poses: PoseTrack) -> np.ndarray:
    """(N - 3, 3) [m] jump_k (module docstring) of the intervals k = 1 .. N - 3 between the poses."""
    dt_s = np.diff(poses.time)
    velocity = np.diff(poses.position_m, axis=0) / dt_s[:, None]
    return (velocity[1:-1] - 0.5 * (velocity[:-2] + velocity[2:])) * dt_s[1:-1, None]


def noisy_steps(position_m: np.ndarray) -> np.ndarray:
    """Sample indices k (increasing) such that the positions (N,3) [m], evenly sampled and under white noise, step
    between samples k and k+1: the difference d_k between the quadratics fitted to the STEP_WINDOW samples on
    either side, both taken half-way between k and k+1, stands out by more than STEP_SIGMAS (its 3 axes, each
    over its robust sigma, 1.4826 x the median absolute d over the drive), and is the largest within a window
    either way; and a step explains the 2 STEP_WINDOW samples about it better than a change of acceleration
    anywhere among them does (_a_step_not_a_manoeuvre). The quadratics follow the vehicle's acceleration, not its
    changes: braking of 3 m/s^2 that starts at once moves d by up to 11 mm, a jerk of 3 m/s^3 by 6 mm, which
    under a low noise (1.5 mm a sample: 0.9 mm on d) stand out as much as a step. None on fewer than
    4 STEP_WINDOW samples."""
    window = STEP_WINDOW
    if len(position_m) < 4 * window:
        return np.zeros(0, np.int64)
    before, after = _edge_filter(window, float(window) - 0.5), _edge_filter(window, -0.5)  # fit at sample offsets 0..
    windows = np.lib.stride_tricks.sliding_window_view(position_m, window, axis=0)  # (N - window + 1, 3, window)
    at_end, at_start = windows @ before, windows @ after  # each window's value just past its end / before its start
    boundary = np.arange(window - 1, len(position_m) - window)  # k: windows k-window+1..k and k+1..k+window
    d = at_start[boundary + 1] - at_end[boundary - window + 1]
    sigma = 1.4826 * np.median(np.abs(d), axis=0)
    z = np.sqrt(np.sum((d / np.maximum(sigma, 0.1 * sigma.max() + 1e-12)) ** 2, axis=1))
    peak = (z > STEP_SIGMAS) & (z >= maximum_filter1d(z, size=2 * window + 1, mode="constant"))
    return np.array([k for k in boundary[peak] if _a_step_not_a_manoeuvre(position_m[k - window + 1:k + window + 1])],
                    dtype=np.int64)


def _a_step_not_a_manoeuvre(position_m: np.ndarray) -> bool:
    """Whether the positions (2W, 3) [m] about a boundary (between samples W-1 and W) are better explained by a
    quadratic with a step there than by a quadratic whose acceleration changes at some sample among them (the
    least sum of squared residuals over the three axes, each model with four coefficients an axis)."""
    half = len(position_m) // 2
    offsets = np.arange(len(position_m), dtype=np.float64) - half + 0.5
    quadratic = np.vander(offsets, 3, increasing=True)
    step = _least_squares_residual(np.column_stack([quadratic, offsets > 0]), position_m)
    manoeuvre = min(_least_squares_residual(np.column_stack([quadratic, np.clip(offsets - at, 0, None) ** 2]),
                                            position_m) for at in offsets[1:-1])
    return step < manoeuvre


def _least_squares_residual(design: np.ndarray, values: np.ndarray) -> float:
    """The sum of squared residuals of the least-squares fit of values (n, k) on design (n, p), over every column."""
    coefficients = np.linalg.lstsq(design, values, rcond=None)[0]
    return float(np.sum((values - design @ coefficients) ** 2))


def _edge_filter(window: int, at: float) -> np.ndarray:
    """(window,) weights whose product with window samples (offsets 0..window-1) is the least-squares quadratic's
    value at offset `at`."""
    offsets = np.arange(window, dtype=np.float64)
    design = np.vander(offsets, 3, increasing=True)
    return np.vander(np.array([at]), 3, increasing=True)[0] @ np.linalg.pinv(design)
