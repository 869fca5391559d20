"""Steps of a recorded trajectory's positions (graphcal.recording.trajectory_steps) and the controls placed about
them (graphcal.calibration.returns.controls_about_steps)."""

import numpy as np

from graphcal.calibration.returns import between_controls, controls_about_steps, control_grid, knots_every
from graphcal.recording.poses import PoseTrack
from graphcal.recording.trajectory_noise import smoothed_poses
from graphcal.recording.trajectory_steps import noisy_steps, position_steps, step_vectors_m


def _drive(rate_hz: float, seconds: float, walk_m_sqrt_s: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(time [s], position [m]) of a vehicle turning a 40 m circle at 8 m/s while braking, with an INS error
    that walks at walk_m_sqrt_s per axis."""
    rng = np.random.default_rng(seed)
    time_s = np.arange(0.0, seconds, 1.0 / rate_hz)
    along_m = 8.0 * time_s - 0.1 * time_s ** 2
    truth = np.column_stack([40 * np.cos(along_m / 40), 40 * np.sin(along_m / 40), 0.02 * time_s])
    walk = np.cumsum(rng.normal(0.0, walk_m_sqrt_s / np.sqrt(rate_hz), truth.shape), axis=0)
    return time_s, truth + walk


def _track(time_s, position_m) -> PoseTrack:
    return PoseTrack.from_rpy(time_s, position_m, np.zeros((len(time_s), 3)))


def test_the_steps_of_an_ins_are_found_and_nothing_else():
    """Three steps of 1.5-6 cm injected after known samples of a drive at 100 Hz whose INS error walks at 5 mm/sqrt(s)
    (0.5 mm a sample) are found, each between its two samples; a step of 3 mm is not (below MIN_STEP_M), nor is
    anything on the drive without steps, on three draws."""
    for seed in range(3):
        time_s, position_m = _drive(100.0, 60.0, 0.005, seed)
        assert len(position_steps(_track(time_s, position_m))) == 0
        steps = {1234: [0.04, -0.03, 0.01], 3000: [0.0, 0.015, 0.0], 4500: [-0.06, 0.0, 0.02], 5200: [0.003, 0, 0]}
        stepped = position_m.copy()
        for after, step_m in steps.items():
            stepped[after + 1:] += step_m
        found = position_steps(_track(time_s, stepped))
        np.testing.assert_array_equal(found, time_s[[[1234, 1235], [3000, 3001], [4500, 4501]]])


def test_controls_stand_either_side_of_each_step():
    """The grid's controls with one on each side of each step inside their span (a grid control within a
    millisecond of one of them gives way), the break at the control after; a return just before a step is
    interpolated almost wholly from the control before it, one just after from the control after; each step's
    vector goes to the control after it (the one outside the span nowhere); the coarse knots keep both controls
    about each step."""
    grid = control_grid(0.0, 0.2, 9.7, 1.0)  # 0, 1, ..., 10
    steps = np.array([[3.0, 3.01], [6.5, 6.51], [12.0, 12.01]])  # the last outside the controls' span
    times, into = controls_about_steps(grid, steps, np.array([[0.01, 0, 0], [0, 0.02, 0], [0, 0, 0.03]]))
    np.testing.assert_allclose(times, [0, 1, 2, 3.0, 3.01, 4, 5, 6, 6.5, 6.51, 7, 8, 9, 10])
    assert np.flatnonzero(np.any(into != 0, axis=1)).tolist() == [4, 9]
    np.testing.assert_array_equal(into[[4, 9]], [[0.01, 0, 0], [0, 0.02, 0]])
    control, alpha = between_controls(np.array([2.999, 3.009, 3.011]), times)
    assert control.tolist() == [2, 3, 4] and alpha[0] > 0.99 and np.isclose(alpha[1], 0.9) and alpha[2] < 0.01
    assert controls_about_steps(grid, np.zeros((0, 2)), np.zeros((0, 3)))[1] is None
    knots = knots_every(len(times), 4, np.array([3, 4, 8, 9]))
    assert {3, 4, 8, 9} <= set(knots.tolist()) and knots[0] == 0 and knots[-1] == len(times) - 1


def test_a_hard_brake_at_ten_poses_a_second_is_no_step():
    """At 10 poses a second a brake of 8 m/s^2 (from 16 m/s, starting and ending at once) changes the velocity
    between intervals by up to 0.8 m/s, 4 cm over a 0.1 s interval: not a step (at most 1 g of acceleration is the
    vehicle's); a 15 cm step there is."""
    time_s = np.arange(0.0, 30.0, 0.1)
    braking = np.clip(time_s - 10.0, 0.0, 1.5)
    along_m = 16.0 * time_s - 4.0 * braking ** 2 - 12.0 * np.clip(time_s - 11.5, 0.0, None)
    position_m = np.column_stack([along_m, np.zeros_like(time_s), np.zeros_like(time_s)])
    assert len(position_steps(_track(time_s, position_m))) == 0
    position_m[201:, 1] += 0.15
    np.testing.assert_array_equal(position_steps(_track(time_s, position_m)), [time_s[[200, 201]]])


def test_steps_under_white_noise_are_kept_by_the_smoothing_and_found():
    """5 mm of white noise a sample over the walking INS of the first test (the fourth-difference noise above the
    1 mm floor: smoothed): the noise hides steps from a sample's jump, the quadratics on either side find steps of
    3-5 cm (noisy_steps), the smoothing runs on either side of each apart, and position_steps finds them, each
    between its two samples, in the smoothed poses (step_vectors_m measures each within 3 of its stated sigmas,
    2-6 mm), which stay within 3 mm RMS (3 axes) of the stepped truth within
    20 samples of the steps (2.2-2.9 mm; one spline over the whole drive: 5.9-7.2 mm there, and no step left to
    find) as elsewhere (2.2-2.4 mm); on the same drives without steps, none is found."""
    for seed in range(3):
        time_s, position_m = _drive(100.0, 60.0, 0.005, seed)
        noise = np.random.default_rng(10 + seed).normal(0.0, 0.005, position_m.shape)
        assert len(noisy_steps(position_m + noise)) == 0
        stepped = position_m.copy()
        for after, step_m in {1234: [0.03, -0.02, 0.0], 3000: [0.0, 0.03, 0.01], 4500: [-0.05, 0.0, 0.02]}.items():
            stepped[after + 1:] += step_m
        assert noisy_steps(stepped + noise).tolist() == [1234, 3000, 4500]
        smooth, measured, left = smoothed_poses(_track(time_s, stepped + noise))
        assert 0.004 < measured.position_m < 0.006
        np.testing.assert_array_equal(position_steps(smooth), time_s[[[1234, 1235], [3000, 3001], [4500, 4501]]])
        step_m, sigma_m = step_vectors_m(smooth, position_steps(smooth), left.position_m)
        np.testing.assert_allclose(step_m, [[0.03, -0.02, 0.0], [0.0, 0.03, 0.01], [-0.05, 0.0, 0.02]], atol=3 * sigma_m)
        assert 0.002 < sigma_m < 0.006
        error_m = np.linalg.norm(smooth.position_m - stepped, axis=1)
        near = np.abs(np.arange(len(time_s))[:, None] - np.array([1234, 3000, 4500])).min(axis=1) < 20
        assert np.sqrt(np.mean(error_m[near] ** 2)) < 0.003 and np.sqrt(np.mean(error_m[~near] ** 2)) < 0.003


def test_two_steps_a_sample_apart_share_their_middle_control():
    """Steps between 2.0 and 2.01 s and between 2.01 and 2.02 s: three controls there, a break after each step,
    no two controls at one time (between_controls would divide by a zero interval)."""
    times, into = controls_about_steps(np.arange(0.0, 5.0), np.array([[2.0, 2.01], [2.01, 2.02]]),
                                       np.array([[0.01, 0, 0], [0, 0.02, 0]]))
    np.testing.assert_allclose(times, [0, 1, 2.0, 2.01, 2.02, 3, 4])
    np.testing.assert_array_equal(into[[3, 4]], [[0.01, 0, 0], [0, 0.02, 0]])
    assert np.flatnonzero(np.any(into != 0, axis=1)).tolist() == [3, 4] and np.all(np.diff(times) > 0)


def test_braking_at_once_under_a_low_noise_is_no_step():
    """Braking at 3 m/s^2 that starts and ends at once moves the quadratics on either side of a boundary by up to
    11 mm, 12 sigmas of their difference under 1.5 mm of noise a sample: a change of acceleration explains those
    samples better than a step, so none is found, the smoothing does not split there and the smoothed poses do not
    step; a 3 cm step on the same drive is found. At 1.5, 3 and 5 mm of noise."""
    time_s = np.arange(0.0, 60.0, 0.01)
    speed_m_s = 12.0 + np.cumsum(np.where((time_s >= 20.0) & (time_s < 23.0), -3.0, 0.0)) * 0.01
    position_m = np.column_stack([np.cumsum(speed_m_s) * 0.01, np.zeros_like(time_s), np.zeros_like(time_s)])
    for noise_m in (0.0015, 0.003, 0.005):
        noisy = position_m + np.random.default_rng(0).normal(0.0, noise_m, position_m.shape)
        assert len(noisy_steps(noisy)) == 0
        smooth, _, _ = smoothed_poses(_track(time_s, noisy))
        assert len(position_steps(smooth)) == 0
        assert np.abs(smooth.position_m - position_m).max() < noise_m
        noisy[3001:, 1] += 0.03
        assert noisy_steps(noisy).tolist() == [3000]
