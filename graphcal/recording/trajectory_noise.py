"""The white noise of a recorded trajectory, measured from its own poses (no truth).

A GNSS/INS trajectory written at 100-200 Hz may carry sample-to-sample noise (a position solution
re-estimated at every epoch, a simulator's white noise); the vehicle's own motion is smooth over a
few samples. The fourth difference of five consecutive samples cancels any cubic (the motion over
20-50 ms) and has unit gain on white noise, so its median absolute value measures the noise as
range_noise.py measures a head's range noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from graphcal.recording.poses import PoseTrack
from graphcal.recording.range_noise import FOURTH_DIFFERENCE, MIN_DIFFERENCES

UNIFORM_TOLERANCE = 0.01  # relative spread of five samples' intervals for their difference to count


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


def measured_pose_noise(poses: PoseTrack) -> PoseNoise:
    """The trajectory's white noise: 1.4826 x the median absolute fourth difference of each position
    axis and each attitude angle (the rotation of every pose relative to the middle one of its five, so
    that yaw's wrap and large angles do not enter), over runs of five evenly spaced samples."""
    time = poses.time
    if len(time) < len(FOURTH_DIFFERENCE) + MIN_DIFFERENCES:
        return PoseNoise(np.nan, np.nan, np.nan)
    width = len(FOURTH_DIFFERENCE)
    steps = np.lib.stride_tricks.sliding_window_view(np.diff(time), width - 1)
    even = np.flatnonzero(np.ptp(steps, axis=1) <= UNIFORM_TOLERANCE * steps.mean(axis=1))
    if len(even) < MIN_DIFFERENCES:
        return PoseNoise(np.nan, np.nan, np.nan)
    windows = even[:, None] + np.arange(width)
    position = np.einsum("nki,k->ni", poses.position_m[windows], FOURTH_DIFFERENCE)
    middle = poses.rotation[windows[:, width // 2]]
    relative = np.stack([(middle.inv() * poses.rotation[windows[:, k]]).as_rotvec() for k in range(width)], axis=1)
    attitude = np.einsum("nki,k->ni", relative, FOURTH_DIFFERENCE)
    return PoseNoise(float(1.4826 * np.median(np.abs(position))), float(1.4826 * np.median(np.abs(attitude))),
                     float(np.median(np.diff(time))))
