"""The recorded trajectory's white noise, measured from its own poses."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from graphcal.recording.poses import PoseTrack
from graphcal.recording.trajectory_noise import measured_pose_noise


def _drive(rate_hz: float, seconds: float = 20.0):
    """A smooth drive: a turn with speed changes, pitch and roll from the accelerations."""
    t = np.arange(0.0, seconds, 1.0 / rate_hz)
    yaw = 0.5 * np.sin(0.2 * t) + 0.03 * t
    speed = 7.0 + 2.0 * np.sin(0.4 * t)
    position = np.column_stack([np.cumsum(speed * np.cos(yaw)) / rate_hz, np.cumsum(speed * np.sin(yaw)) / rate_hz,
                                0.3 * np.sin(0.05 * t)])
    rpy = np.column_stack([0.01 * np.sin(0.3 * t), 0.02 * np.cos(0.4 * t), yaw])
    return t, position, rpy


@pytest.mark.parametrize("rate_hz", [100.0, 200.0])
def test_white_pose_noise_is_measured_and_smooth_motion_is_not(rate_hz):
    t, position, rpy = _drive(rate_hz)
    rng = np.random.default_rng(3)
    clean = measured_pose_noise(PoseTrack(t, position, Rotation.from_euler("xyz", rpy)))
    assert clean.position_m < 1e-5 and clean.attitude_rad < 1e-6
    assert clean.interval_s == pytest.approx(1.0 / rate_hz)
    noisy_rotation = Rotation.from_euler("xyz", rpy) * Rotation.from_rotvec(rng.normal(0, np.radians(0.005), (len(t), 3)))
    noisy = measured_pose_noise(PoseTrack(t, position + rng.normal(0, 0.005, position.shape), noisy_rotation))
    assert noisy.position_m == pytest.approx(0.005, rel=0.05)
    assert noisy.attitude_rad == pytest.approx(np.radians(0.005), rel=0.05)


def test_uneven_or_short_trajectories_leave_the_noise_unknown():
    t, position, rpy = _drive(100.0, 0.5)
    assert np.isnan(measured_pose_noise(PoseTrack(t, position, Rotation.from_euler("xyz", rpy))).position_m)
    t, position, rpy = _drive(100.0)
    jittered = t + np.random.default_rng(0).uniform(0, 0.004, len(t))  # no five samples evenly spaced
    assert np.isnan(measured_pose_noise(PoseTrack(np.sort(jittered), position, Rotation.from_euler("xyz", rpy))).position_m)
