"""Steps in a recorded trajectory's positions, found from its own poses (no truth).

A GNSS-aided INS that takes a GNSS fix into its solution moves its output position at once: the recorded
position steps between two samples by centimetres, a jump no vehicle makes in 10 ms (7 cm in 10 ms is 7 m/s
gained and lost in a sample). Trajectory corrections interpolated linearly between controls a second apart
cannot follow a step: the returns of that interval keep up to half of it. A control on each side of the step
(calibration/returns.py) lets the corrections step with the INS.

A step shows in the change of velocity at one sample against its neighbours: for the interval k between samples
k and k+1, jump_k = (v_k - (v_(k-1) + v_(k+1)) / 2) dt_k [m] (v the velocity over each interval) is the step
itself at k and minus half of it at k - 1 and k + 1; the vehicle's own acceleration a gives a dt^2 (3 m/s^2 over
10 ms: 0.3 mm; at most MAX_ACCELERATION_M_S2 dt^2, which bounds the jumps counted as steps from below: a
trajectory of 10 poses a second cannot tell a 5 cm step from a hard brake) and a random walk of the INS's error
(5 mm/sqrt(s): 0.6 mm) far less.
"""

from __future__ import annotations

import numpy as np

from graphcal.recording.poses import PoseTrack

STEP_TIMES_MEDIAN = 10.0  # a step's jump is at least this many times the median jump over the drive ...
MIN_STEP_M = 0.01  # ... and at least this [m]: a smaller step leaves at most half of it, within a 1 cm range noise
MAX_ACCELERATION_M_S2 = 10.0  # ... and above what a vehicle's acceleration (1 g) gives over the interval


def position_steps(poses: PoseTrack) -> np.ndarray:
    """(S, 2) times [s] of the two samples between which the recorded position steps (module docstring): the
    intervals whose jump is above STEP_TIMES_MEDIAN x the drive's median jump and MIN_STEP_M, and the largest of
    the three about it, and above MAX_ACCELERATION_M_S2 dt^2; none on a track of fewer than five poses."""
    time_s, position_m = poses.time, poses.position_m
    if len(time_s) < 5:
        return np.zeros((0, 2))
    dt_s = np.diff(time_s)
    velocity = np.diff(position_m, axis=0) / dt_s[:, None]
    jump_m = np.linalg.norm((velocity[1:-1] - 0.5 * (velocity[:-2] + velocity[2:])) * dt_s[1:-1, None], axis=1)
    threshold_m = max(STEP_TIMES_MEDIAN * float(np.median(jump_m)), MIN_STEP_M)
    padded = np.r_[0.0, jump_m, 0.0]
    peak = ((jump_m > np.maximum(threshold_m, MAX_ACCELERATION_M_S2 * dt_s[1:-1] ** 2))
            & (jump_m >= padded[:-2]) & (jump_m >= padded[2:]))
    interval = np.flatnonzero(peak) + 1  # jump_m[i] is the interval i + 1's
    return np.column_stack([time_s[interval], time_s[interval + 1]])
