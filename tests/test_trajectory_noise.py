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
    sample: the smoothed poses are within a third (position) and 0.4 (attitude) of the noise of the truth
    (measured: 0.21-0.25 in position, 0.23-0.30 in attitude, the bounce's pitch the most); noise-free poses
    come back unchanged, with nothing left (PoseNoise.none())."""
    t, position, rpy = _drive(200.0)
    bounce = np.sin(2 * np.pi * 1.5 * t)
    position[:, 2] += 0.03 * bounce
    rpy[:, 1] += np.radians(0.3) * bounce
    truth = PoseTrack(t, position, Rotation.from_euler("xyz", rpy))
    kept, _, nothing_left = smoothed_poses(truth)
    assert kept is truth and nothing_left.interval_s == 0
    rng = np.random.default_rng(5)
    noisy = PoseTrack(t, position + rng.normal(0, 0.005, position.shape),
                      truth.rotation * Rotation.from_rotvec(rng.normal(0, np.radians(0.005), (len(t), 3))))
    smooth, noise, left = smoothed_poses(noisy)
    assert noise.position_m == pytest.approx(0.005, rel=0.05)
    position_error_m = np.sqrt(np.mean((smooth.position_m - position) ** 2, axis=0))
    attitude_error_rad = np.sqrt(np.mean((truth.rotation.inv() * smooth.rotation).as_rotvec() ** 2, axis=0))
    assert np.all(position_error_m < 0.005 / 3), position_error_m
    assert np.all(attitude_error_rad < np.radians(0.005) / 2.5), np.degrees(attitude_error_rad)
    # what the smoothing leaves, as the calibration's sigmas count it: its size, and shared over interval_s (the
    # error's means over windows that long keep it) (measured: 1.04 against 1.15 mm, 0.0011 against 0.0013 deg;
    # window means 0.99 mm over 21 samples)
    assert left.position_m == pytest.approx(np.sqrt(np.mean(position_error_m ** 2)), rel=0.25)
    assert left.attitude_rad == pytest.approx(np.sqrt(np.mean(attitude_error_rad ** 2)), rel=0.25)
    per_window = int(round(left.interval_s / noise.interval_s))
    assert 5 <= per_window <= 100, left
    windows = (smooth.position_m - position)[:len(t) // per_window * per_window].reshape(-1, per_window, 3).mean(axis=1)
    assert windows.std() == pytest.approx(left.position_m, rel=0.3)


def test_the_smoothing_does_not_cut_the_corner_of_a_turn():
    """A 90 deg turn at 30 deg/s and 8 m/s (4.2 m/s^2 sideways, entered and left in 0.5 s, the body rolling
    1.5 deg) under 5 mm and 0.005 deg of white noise: no position is off by the noise sigma (measured: at most
    0.8 of it; one penalty for a whole drive of tools/foreign_sim put a position 3.6 sigmas off), the attitude within 0.4 of it in
    RMS (measured 0.18-0.33; the roll's kinks at the turn's ends up to 3.9 sigmas)."""
    t = np.arange(0.0, 12.0, 1.0 / 200.0)
    yaw_rate = np.radians(30.0) * np.clip((t - 4.0) / 0.5, 0, 1) * np.clip((7.5 - t) / 0.5, 0, 1)
    yaw = np.cumsum(yaw_rate) / 200.0
    position = np.column_stack([np.cumsum(8.0 * np.cos(yaw)) / 200.0, np.cumsum(8.0 * np.sin(yaw)) / 200.0,
                                np.zeros_like(t)])
    truth = Rotation.from_euler("xyz", np.column_stack([-np.radians(1.5) * yaw_rate / np.radians(30.0),
                                                       np.zeros_like(t), yaw]))
    rng = np.random.default_rng(7)
    smooth, _, _ = smoothed_poses(PoseTrack(t, position + rng.normal(0, 0.005, position.shape),
                                         truth * Rotation.from_rotvec(rng.normal(0, np.radians(0.005), (len(t), 3)))))
    assert np.abs(smooth.position_m - position).max() < 0.005
    attitude_error_rad = np.sqrt(np.mean((truth.inv() * smooth.rotation).as_rotvec() ** 2, axis=0))
    assert np.all(attitude_error_rad < 0.4 * np.radians(0.005)), np.degrees(attitude_error_rad)


def test_roughness_eigenbasis_gives_scipys_smoothing_spline():
    """The penalty search's residual (Demmler-Reinsch eigenbasis of K = Q R^-1 Q^T) equals the residual of
    scipy's make_smoothing_spline at the same penalty, on unevenly spaced times."""
    from scipy.interpolate import make_smoothing_spline

    from graphcal.recording.trajectory_noise import _roughness

    rng = np.random.default_rng(5)
    t = 345600.0 + np.cumsum(rng.uniform(0.004, 0.006, 150))
    y = np.sin(3 * (t - t[0])) + rng.normal(0, 0.01, len(t))
    d, u = np.linalg.eigh(_roughness(t))
    for lam in (1e-8, 1e-5, 1e-2):
        shrink = lam * np.maximum(d, 0)
        residual = u @ (shrink / (1 + shrink) * (u.T @ y))
        np.testing.assert_allclose(residual, y - make_smoothing_spline(t, y, lam=lam)(t), atol=1e-9)
