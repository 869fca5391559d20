"""The white noise of a recorded trajectory, measured from its own poses (no truth).

A GNSS/INS trajectory written at 100-200 Hz may carry sample-to-sample noise (a position solution
re-estimated at every epoch, a simulator's white noise); the vehicle's own motion is smooth over a
few samples. The fourth difference of five consecutive samples cancels any cubic (the motion over
20-50 ms) and has unit gain on white noise, so its median absolute value measures the noise as
range_noise.py measures a head's range noise.

Noise above a floor (an INS re-solved at every epoch, not a smoothed trajectory) is smoothed out before
anything uses the poses: each position axis and attitude angle is a cubic smoothing spline whose penalty follows
the discrepancy principle window by window (docs/reference/math.md "The trajectory's jitter"). What the
smoothing leaves is not white: an error of a fraction of the noise, shared by the poses of a few tens of
milliseconds (smoothing_error), which every return fired then shares.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import make_smoothing_spline

from graphcal.recording.poses import PoseTrack
from graphcal.recording.range_noise import FOURTH_DIFFERENCE, MIN_DIFFERENCES
from graphcal.recording.rotations import rotation_from_rpy_deg, unwrap_deg
from graphcal.recording.trajectory_steps import noisy_steps

UNIFORM_TOLERANCE = 0.01  # relative spread of five samples' intervals for their difference to count
# white noise above which the poses are smoothed: a post-processed (smoothed) GNSS/INS trajectory is far below
SMOOTH_ABOVE_M = 1e-3
SMOOTH_ABOVE_RAD = np.radians(1e-3)
PENALTY_WINDOW_S = 1.0  # seconds of each window where a channel's penalty is chosen
LEFT_NOISE_SEED = 0  # the white noise the smoother is run on to measure what it leaves
PENALTY_SPAN = 2.0  # decades between the least and the largest window penalty (the weights' conditioning)
PENALTY_BISECTIONS = 8  # halvings of the log10 penalty's bracket [-12, 6]: 0.07 decade


@dataclass(frozen=True)
class PoseNoise:
    """1-sigma noise of the recorded poses: position [m] per axis, attitude [rad] per axis, one draw per
    interval_s [s] (white noise: the median sample interval; what smoothing leaves: the time its error is shared
    over). NaN: too few evenly spaced samples to tell."""

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


def smoothed_poses(poses: PoseTrack) -> tuple[PoseTrack, PoseNoise, PoseNoise]:
    """The poses with their white noise smoothed out where it is above SMOOTH_ABOVE_M or SMOOTH_ABOVE_RAD (the
    same object, unchanged, where it is below or cannot be measured), the noise measured on them, and the error
    the smoothing leaves (_PenaltyWindows.smoothed; PoseNoise.none() when not smoothed). Each position axis [m]
    and attitude angle (roll, pitch, unwrapped yaw [deg]) is a cubic smoothing spline of time (scipy
    make_smoothing_spline) with penalties chosen for that channel's own noise (_PenaltyWindows.smoothed), on
    either side of each step of the positions apart (trajectory_steps.noisy_steps: a GNSS update's jump, which
    one spline would spread over its window)."""
    noise = measured_pose_noise(poses)
    if not (noise.position_m > SMOOTH_ABOVE_M or noise.attitude_rad > SMOOTH_ABOVE_RAD):
        return poses, noise, PoseNoise.none()
    rpy_deg = poses.rpy_deg
    rpy_deg[:, 2] = unwrap_deg(rpy_deg[:, 2])
    channels = np.column_stack([poses.position_m, rpy_deg])
    pieces = np.split(np.arange(len(poses.time)), noisy_steps(poses.position_m) + 1)  # smoothed apart: steps kept
    parts = [_PenaltyWindows.of(poses.time[rows]).smoothed(channels[rows]) for rows in pieces]
    smooth = np.concatenate([part[0] for part in parts])
    weight = np.array([len(rows) for rows in pieces]) / len(poses.time)
    left = np.sqrt(sum(w * part[1] ** 2 for w, part in zip(weight, parts)))
    interval_s = float(np.median(np.diff(poses.time)))
    share = sum(w * interval_s / part[2] for w, part in zip(weight, parts) if part[2] > 0)  # smoothed's g^2
    left_noise = PoseNoise(float(np.sqrt(np.mean(left[:3] ** 2))), float(np.radians(np.sqrt(np.mean(left[3:] ** 2)))),
                           interval_s / share if share > 0 else 0.0)
    return PoseTrack(poses.time, smooth[:, :3], rotation_from_rpy_deg(smooth[:, 3:])), noise, left_noise


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

    def smoothed(self, channels: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """(N,C) channels, each smoothed for its own white noise (_robust_sigma of its fourth differences over
        the even runs); a channel whose noise is nil is returned unchanged. The smoothing follows the motion: a
        penalty is chosen on each window (_discrepancy_log_penalties, at most PENALTY_SPAN decades above the
        channel's smallest), and the spline's weights make each window's penalty its own (weight = the largest
        penalty over this window's, log-interpolated between window centres). One penalty for the whole drive
        cuts the corners of the turns by several noise sigmas, a lateral error that the lever arm's height then
        takes up against the roll in the turn.

        Also what the smoothing leaves of the noise: (C,) its 1-sigma per channel (in the channel's unit) and the
        time [s] over which it is shared. The spline is linear in the values once its penalties are chosen, so the
        same spline run on unit white noise (seeded) leaves its noise's share g^2 (the mean of the squared smoother
        weights): sigma g per channel, and, as the spline averages about 1/g^2 samples, an error shared by the
        samples of interval / g^2 (docs/reference/math.md "The trajectory's jitter")."""
        sigma = (np.array([_robust_sigma(channels[self.runs, k] @ FOURTH_DIFFERENCE)
                           for k in range(channels.shape[1])]) if len(self.runs) else np.zeros(channels.shape[1]))
        noisy = np.flatnonzero(sigma > 0)
        left = np.zeros(channels.shape[1])
        if not len(noisy):
            return channels, left, 0.0
        time_s, size = self.time_s, self.size
        log_penalty = np.array([_discrepancy_log_penalties(time_s[a:a + size], channels[a:a + size, noisy],
                                                           sigma[noisy]) for a in self.starts])
        log_penalty = np.minimum(log_penalty, log_penalty.min(axis=0) + PENALTY_SPAN)
        centres_s = time_s[np.minimum(self.starts + size // 2, len(time_s) - 1)]
        smooth, unit = channels.copy(), np.random.default_rng(LEFT_NOISE_SEED).standard_normal(len(time_s))
        for column, k in enumerate(noisy):
            log_weight = log_penalty[:, column].max() - np.interp(time_s, centres_s, log_penalty[:, column])
            weight, penalty = 10.0 ** log_weight, 10.0 ** log_penalty[:, column].max()
            offset = channels[0, k]
            smooth[:, k] = make_smoothing_spline(time_s, channels[:, k] - offset, w=weight, lam=penalty)(time_s) + offset
            unit_left = make_smoothing_spline(time_s, unit, w=weight, lam=penalty)(time_s)
            left[k] = sigma[k] * np.sqrt(np.mean(unit_left ** 2))
        share = np.mean((left[noisy] / sigma[noisy]) ** 2)
        return smooth, left, float(np.median(np.diff(time_s)) / share)


def _roughness(time_s: np.ndarray) -> np.ndarray:
    """(n,n) K with g^T K g = the integral of g''^2 [units^2/s^3] for the natural cubic spline through the values
    g at time_s [s] (Green and Silverman 1994, Nonparametric Regression and Generalized Linear Models, eq. 2.3:
    K = Q R^-1 Q^T). The unweighted smoothing spline of values y with penalty lam is (I + lam K)^-1 y, the same
    objective as scipy's make_smoothing_spline."""
    h = np.diff(time_s)
    n, inner = len(time_s), np.arange(len(time_s) - 2)
    q = np.zeros((n, n - 2))
    q[inner, inner], q[inner + 1, inner], q[inner + 2, inner] = 1 / h[:-1], -1 / h[:-1] - 1 / h[1:], 1 / h[1:]
    r = np.diag((h[:-1] + h[1:]) / 3) + np.diag(h[1:-1] / 6, 1) + np.diag(h[1:-1] / 6, -1)
    return q @ np.linalg.solve(r, q.T)


def _discrepancy_log_penalties(time_s: np.ndarray, values: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """log10 of each column's smoothing-spline penalty whose residual RMS equals that column's sigma (the
    discrepancy principle; bisection on the log over [-12, 6], PENALTY_BISECTIONS halvings). In the eigenbasis
    of the roughness (Demmler-Reinsch: K = U diag(d) U^T) the residual of penalty lam is
    U diag(lam d / (1 + lam d)) U^T y, so one eigendecomposition serves every penalty and column."""
    d, u = np.linalg.eigh(_roughness(time_s))
    z2 = (u.T @ (values - values.mean(axis=0))) ** 2
    d = np.maximum(d, 0.0)[:, None]
    low, high = np.full(values.shape[1], -12.0), np.full(values.shape[1], 6.0)
    for _ in range(PENALTY_BISECTIONS):
        middle = 0.5 * (low + high)
        shrink = 10.0 ** middle * d
        residual_rms = np.sqrt(np.sum((shrink / (1 + shrink)) ** 2 * z2, axis=0) / len(time_s))
        below = residual_rms < sigma
        low, high = np.where(below, middle, low), np.where(below, high, middle)
    return 0.5 * (low + high)
