"""The recorded trajectory's white noise, measured from its own poses."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from graphcal.recording.poses import PoseTrack
from graphcal.recording.trajectory_noise import measured_pose_noise, smoothed_poses


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


def test_white_pose_noise_is_smoothed_out_and_clean_poses_are_kept():
    """A drive with a 1.5 Hz body bounce (3 cm, 0.3 deg) under 5 mm and 0.005 deg of white noise a 200 Hz
    sample: the smoothed poses are within half the noise of the truth (measured: 0.19-0.31 of it in position,
    0.08-0.37 in attitude, the bounce's pitch the most); noise-free poses come back unchanged."""
    t, position, rpy = _drive(200.0)
    bounce = np.sin(2 * np.pi * 1.5 * t)
    position[:, 2] += 0.03 * bounce
    rpy[:, 1] += np.radians(0.3) * bounce
    truth = PoseTrack(t, position, Rotation.from_euler("xyz", rpy))
    assert smoothed_poses(truth)[0] is truth
    rng = np.random.default_rng(5)
    noisy = PoseTrack(t, position + rng.normal(0, 0.005, position.shape),
                      truth.rotation * Rotation.from_rotvec(rng.normal(0, np.radians(0.005), (len(t), 3))))
    smooth, noise = smoothed_poses(noisy)
    assert noise.position_m == pytest.approx(0.005, rel=0.05)
    position_error_m = np.sqrt(np.mean((smooth.position_m - position) ** 2, axis=0))
    attitude_error_rad = np.sqrt(np.mean((truth.rotation.inv() * smooth.rotation).as_rotvec() ** 2, axis=0))
    assert np.all(position_error_m < 0.005 / 2), position_error_m
    assert np.all(attitude_error_rad < np.radians(0.005) / 2), np.degrees(attitude_error_rad)
