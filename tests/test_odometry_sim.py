"""Simulated odometry.csv and its dead reckoning (seed 002 eq. 1-3) against closed forms."""

import numpy as np
import pytest
from pydantic import ValidationError

from graphcal.deskewing.dead_reckoning import increments, integrate, odometry_track
from graphcal.recording.odometry import Odometry
from graphcal.recording.directory import Recording
from graphcal.simulation.drive import Drive, straight, turn
from graphcal.simulation.odometry import simulate_odometry
from graphcal.simulation.scenario import OdometrySpec
from graphcal.simulation.script import load_scenario_builder
from graphcal.simulation.simulator import simulate

RADIUS_M, ANGLE_DEG, SPEED = 12.0, 60.0, 6.0


def arc_odometry(spec: OdometrySpec, seed: int = 0) -> tuple[Odometry, Drive]:
    drive = Drive(segments=turn(RADIUS_M, ANGLE_DEG), speed_knots=[(0.0, SPEED)])
    duration = RADIUS_M * np.radians(ANGLE_DEG) / SPEED
    return simulate_odometry(drive, spec, 50.0, duration, np.random.default_rng(seed)), drive


def circle(odometry: Odometry) -> tuple[np.ndarray, np.ndarray]:
    """Independent closed form: a left turn of radius R from the origin heading +x."""
    psi = SPEED * (odometry.time - odometry.time[0]) / RADIUS_M
    return np.column_stack([RADIUS_M * np.sin(psi), RADIUS_M * (1 - np.cos(psi))]), psi


@pytest.mark.parametrize("gyro", [False, True])
def test_integration_follows_the_constant_curvature_arc(gyro):
    odometry, _ = arc_odometry(OdometrySpec(gyro=gyro))
    track = odometry_track(odometry, use_gyro=gyro)
    xy, psi = circle(odometry)
    np.testing.assert_allclose(track.position_m[:, :2], xy, atol=1e-5)  # 12.6 m of arc in 209 steps of 10 ms
    np.testing.assert_allclose(np.radians(track.rpy_deg[:, 2]), psi, atol=1e-6)
    np.testing.assert_array_equal(track.position_m[:, 2], 0.0)  # planar


def test_increments_are_eq_1_and_2():
    r, track_m = 0.3, 1.5
    time = np.arange(4.0)
    left, right = np.array([0.0, 1.0, 2.0, 2.0]), np.array([0.0, 1.0, 3.0, 4.0])
    dx, dtheta = increments(Odometry(time, left, right, r, track_m))
    np.testing.assert_allclose(dx, [0.3, 0.45, 0.15])  # r (dR + dL) / 2
    np.testing.assert_allclose(dtheta, [0.0, 0.2, 0.2])  # r (dR - dL) / L
    x, y, theta = integrate(np.array([1.0, 1.0]), np.array([np.pi / 2, 0.0]))
    # eq. 3: the first step leaves along the mid-heading pi/4, the second along pi/2
    np.testing.assert_allclose(x, [0, np.sqrt(0.5), np.sqrt(0.5)], atol=1e-15)
    np.testing.assert_allclose(y, [0, np.sqrt(0.5), np.sqrt(0.5) + 1], atol=1e-15)
    np.testing.assert_allclose(theta, [0, np.pi / 2, np.pi / 2])


def test_gyro_rate_and_wheel_radius_error():
    odometry, _ = arc_odometry(OdometrySpec(gyro=True, wheel_radius_error=0.02))
    np.testing.assert_allclose(odometry.yaw_rate_rad_s, SPEED / RADIUS_M, rtol=1e-6)
    track = odometry_track(odometry, use_gyro=True)
    driven = np.sum(np.linalg.norm(np.diff(track.position_m, axis=0), axis=1))
    # the wheels turn by path / true radius and are read with the nominal one: 2 % short
    assert driven == pytest.approx(RADIUS_M * np.radians(ANGLE_DEG) / 1.02, rel=1e-5)


def test_wheel_noise_has_its_sigma_and_follows_the_seed():
    clean, _ = arc_odometry(OdometrySpec())
    noisy, _ = arc_odometry(OdometrySpec(wheel_noise_rad=0.01, gyro=True, gyro_noise_rad_s=0.02), seed=3)
    again, _ = arc_odometry(OdometrySpec(wheel_noise_rad=0.01, gyro=True, gyro_noise_rad_s=0.02), seed=3)
    np.testing.assert_array_equal(noisy.wheel_left_rad, again.wheel_left_rad)
    slip = np.diff(np.concatenate([noisy.wheel_left_rad - clean.wheel_left_rad,
                                   noisy.wheel_right_rad - clean.wheel_right_rad]))
    assert np.std(slip) == pytest.approx(0.01, rel=0.15)
    assert np.std(noisy.yaw_rate_rad_s - SPEED / RADIUS_M) == pytest.approx(0.02, rel=0.2)


def test_scenarios_write_odometry_csv_and_it_round_trips(tmp_path):
    recording = simulate(load_scenario_builder("deskew_rotation")(size=0.01), quiet=True)
    odometry = recording.odometry
    assert odometry is not None and odometry.yaw_rate_rad_s is not None
    np.testing.assert_allclose(odometry.yaw_rate_rad_s, np.radians(25.0), rtol=1e-6)
    assert odometry.time[0] <= recording.points.read(["time"])["time"][0]
    loaded = Recording.load(recording.save(tmp_path / "rec")).odometry
    assert (loaded.wheel_radius_m, loaded.track_m) == (0.31, 1.60)
    np.testing.assert_allclose(loaded.wheel_right_rad, odometry.wheel_right_rad, atol=1e-9)
    np.testing.assert_allclose(loaded.yaw_rate_rad_s, odometry.yaw_rate_rad_s, atol=1e-9)
    straight_drive = Drive(segments=straight(30.0), speed_knots=[(0.0, 10.0)])
    flat = simulate_odometry(straight_drive, OdometrySpec(gyro=True), 0.0, 2.0, np.random.default_rng(0))
    np.testing.assert_allclose(flat.wheel_left_rad, flat.wheel_right_rad)
    np.testing.assert_allclose(flat.wheel_left_rad[-1], 20.0 / 0.31)
    np.testing.assert_allclose(flat.yaw_rate_rad_s, 0.0, atol=1e-12)


def test_bad_odometry_settings_are_refused():
    with pytest.raises(ValidationError, match="wheel_radius_error"):
        OdometrySpec(wheel_radius_error=0.7)
    with pytest.raises(ValidationError, match="track_m"):
        OdometrySpec(track_m=0.0)
    with pytest.raises(ValidationError, match="wheel_noise_rad"):
        OdometrySpec(wheel_noise_rad=-1.0)
