"""The white noise of a recorded trajectory, measured from its own poses (no truth).

A GNSS/INS trajectory written at 100-200 Hz may carry sample-to-sample noise (a position solution
re-estimated at every epoch, a simulator's white noise); the vehicle's own motion is smooth over a
few samples. The fourth difference of five consecutive samples cancels any cubic (the motion over
20-50 ms) and has unit gain on white noise, so its median absolute value measures the noise as
range_noise.py measures a head's range noise.

Noise above a floor (an INS re-solved at every epoch, not a smoothed trajectory) is smoothed out before
anything uses the poses: each position axis and attitude angle is a cubic smoothing spline whose penalty follows
the discrepancy principle window by window (docs/reference/math.md "The trajectory's jitter").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import make_smoothing_spline

from graphcal.recording.poses import PoseTrack
from graphcal.recording.range_noise import FOURTH_DIFFERENCE, MIN_DIFFERENCES
from graphcal.recording.rotations import rotation_from_rpy_deg, unwrap_deg

UNIFORM_TOLERANCE = 0.01  # relative spread of five samples' intervals for their difference to count
# white noise above which the poses are smoothed: a post-processed (smoothed) GNSS/INS trajectory is far below
SMOOTH_ABOVE_M = 1e-3
SMOOTH_ABOVE_RAD = np.radians(1e-3)
PENALTY_WINDOW_S = 1.0  # seconds of each window where a channel's penalty is chosen
PENALTY_SPAN = 2.0  # decades between the least and the largest window penalty (the weights' conditioning)
PENALTY_BISECTIONS = 8  # halvings of the log10 penalty's bracket [-12, 6]: 0.07 decade


@dataclass(frozen=True)
class PoseNoise:
    """1-sigma white noise of the recorded poses: position [m] per axis, attitude [rad] per axis, at
    samples interval_s [s] apart (the median interval). NaN: too few evenly spaced samples to tell."""

    position_m: float
    attitude_rad: float
    interval_s: float

    @classmethod
    def none(cls) -> PoseNoise:
        return cls(0.0, 0.0, 0.0)


def _even_runs(time_s: np.ndarray) -> np.ndarray:
    """(K,5) indices of runs of five evenly spaced samples (their intervals within UNIFORM_TOLERANCE)."""
    width = len(FOURTH_DIFFERENCE)
    if len(time_s) < width:
        return np.zeros((0, width), dtype=np.int64)
    steps = np.lib.stride_tricks.sliding_window_view(np.diff(time_s), width - 1)
    even = np.flatnonzero(np.ptp(steps, axis=1) <= UNIFORM_TOLERANCE * steps.mean(axis=1))
    return even[:, None] + np.arange(width)


def measured_pose_noise(poses: PoseTrack) -> PoseNoise:
    """The trajectory's white noise: 1.4826 x the median absolute fourth difference of each position
    axis and each attitude angle (the rotation of every pose relative to the middle one of its five, so
    that yaw's wrap and large angles do not enter), over runs of five evenly spaced samples."""
    time = poses.time
    width = len(FOURTH_DIFFERENCE)
    windows = _even_runs(time)
    if len(windows) < MIN_DIFFERENCES:
        return PoseNoise(np.nan, np.nan, np.nan)
    position = np.einsum("nki,k->ni", poses.position_m[windows], FOURTH_DIFFERENCE)
    middle = poses.rotation[windows[:, width // 2]]
    relative = np.stack([(middle.inv() * poses.rotation[windows[:, k]]).as_rotvec() for k in range(width)], axis=1)
    attitude = np.einsum("nki,k->ni", relative, FOURTH_DIFFERENCE)
    return PoseNoise(_robust_sigma(position), _robust_sigma(attitude), float(np.median(np.diff(time))))


def smoothed_poses(poses: PoseTrack) -> tuple[PoseTrack, PoseNoise]:
    """The poses with their white noise smoothed out where it is above SMOOTH_ABOVE_M or SMOOTH_ABOVE_RAD (the
    same object, unchanged, where it is below or cannot be measured), and the noise measured on them. Each
    position axis [m] and attitude angle (roll, pitch, unwrapped yaw [deg]) is a cubic smoothing spline of time
    (scipy make_smoothing_spline) with penalties chosen for that channel's own noise (_smoothed_channel)."""
    noise = measured_pose_noise(poses)
    if not (noise.position_m > SMOOTH_ABOVE_M or noise.attitude_rad > SMOOTH_ABOVE_RAD):
        return poses, noise
    rpy_deg = poses.rpy_deg
    rpy_deg[:, 2] = unwrap_deg(rpy_deg[:, 2])
    channels = np.column_stack([poses.position_m, rpy_deg])
    windows = _PenaltyWindows.of(poses.time)
    smooth = np.column_stack([windows.smoothed(channels[:, k]) for k in range(channels.shape[1])])
    return PoseTrack(poses.time, smooth[:, :3], rotation_from_rpy_deg(smooth[:, 3:])), noise


def _robust_sigma(differences: np.ndarray) -> float:
    """1-sigma of white noise from its fourth differences: 1.4826 x their median absolute value."""
    return float(1.4826 * np.median(np.abs(differences)))


@dataclass(frozen=True)
class _PenaltyWindows:
    """The windows of PENALTY_WINDOW_S [s] (at least 20 samples) where the penalties of every channel of one
    trajectory are chosen: their first samples (starts), their length in samples (size), the trajectory's time
    [s] and its runs of five evenly spaced samples (runs: the noise's fourth differences)."""

    time_s: np.ndarray
    runs: np.ndarray
    starts: np.ndarray
    size: int

    @classmethod
    def of(cls, time_s: np.ndarray) -> _PenaltyWindows:
        size = max(int(round(PENALTY_WINDOW_S / float(np.median(np.diff(time_s))))), 20)
        return cls(time_s, _even_runs(time_s), np.arange(0, max(len(time_s) - size, 0) + 1, size), size)

    def smoothed(self, values: np.ndarray) -> np.ndarray:
        """One channel smoothed for its own white noise (_robust_sigma of its fourth differences over the even
        runs); unchanged where the noise is nil. The smoothing follows the motion: a penalty is chosen on each
        window (at most PENALTY_SPAN decades above the smallest), and the spline's weights make each window's
        penalty its own (weight = the largest penalty over this window's, log-interpolated between window
        centres). One penalty for the whole drive cuts the corners of the turns by several noise sigmas, a
        lateral error that the lever arm's height then takes up against the roll in the turn."""
        sigma = _robust_sigma(values[self.runs] @ FOURTH_DIFFERENCE) if len(self.runs) else 0.0
        if not sigma > 0:
            return values
        time_s, size, offset = self.time_s, self.size, values[0]
        log_penalty = np.array([_discrepancy_penalty(time_s[a:a + size], values[a:a + size] - offset, sigma)
                                for a in self.starts])
        log_penalty = np.minimum(log_penalty, log_penalty.min() + PENALTY_SPAN)
        centres_s = time_s[np.minimum(self.starts + size // 2, len(time_s) - 1)]
        log_weight = log_penalty.max() - np.interp(time_s, centres_s, log_penalty)
        spline = make_smoothing_spline(time_s, values - offset, w=10.0 ** log_weight, lam=10.0 ** log_penalty.max())
        return spline(time_s) + offset


def _discrepancy_penalty(time_s: np.ndarray, values: np.ndarray, sigma: float) -> float:
    """log10 of the smoothing spline's penalty whose residual RMS equals sigma (the discrepancy principle:
    the residual grows with the penalty; bisection on its log over [-12, 6])."""
    low, high = -12.0, 6.0
    for _ in range(PENALTY_BISECTIONS):
        middle = 0.5 * (low + high)
        residual = values - make_smoothing_spline(time_s, values, lam=10.0 ** middle)(time_s)
        low, high = (middle, high) if np.sqrt(np.mean(residual ** 2)) < sigma else (low, middle)
    return 0.5 * (low + high)
