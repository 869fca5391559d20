"""The outer loop: its stopping rule on a J curve that has stopped falling (on_plateau; the mean of the plateau's
iterates; a fine phase run again goes on from its J curve), the step that switches phases and stops it (step_size),
and its Levenberg-Marquardt on a badly scaled graph (levenberg_marquardt)."""

import gtsam
import numpy as np
import pytest

from graphcal.calibration.priors import HELD_SIGMA
from graphcal.calibration.levenberg_marquardt import levenberg_marquardt
from graphcal.calibration.problem import on_plateau, step_size
from graphcal.calibration.returns import Estimate

# fine-phase J [cm^2] of sim6_turn at full size, joint_trajectory (session 7 benchmark): it stops
# falling near 0.001 while the association's jitter keeps the largest step above tolerance_m
FULL_SIZE_FINE = [0.00111, 0.00111, 0.00101, 0.00100, 0.00099, 0.00098, 0.00099, 0.00099, 0.00104, 0.00104,
                  0.00101, 0.00101, 0.00098, 0.00099, 0.00099, 0.00099, 0.00097]


def first_stop(energies, iterations=6, improvement=0.01):
    return next((n for n in range(1, len(energies) + 1) if on_plateau(energies[:n], iterations, improvement)), None)


def test_a_curve_still_falling_does_not_stop():
    assert first_stop([0.95 ** k for k in range(30)]) is None
    # 0.1 % per iteration: six iterations fall 0.6 %, less than the 1 % a new low needs
    assert first_stop([0.999 ** k for k in range(30)]) == 7


def test_a_flat_jittering_curve_stops_once_no_new_low_came_in_the_window():
    # new lows (by 1 %) at the 3rd and 6th values; six values without one after the 6th: stop at the 12th
    assert first_stop(FULL_SIZE_FINE) == 12
    assert first_stop(FULL_SIZE_FINE, iterations=20) is None


def test_too_few_iterations_never_stop():
    assert not on_plateau([1.0] * 6, 6, 0.01)
    assert on_plateau([1.0] * 7, 6, 0.01)


def _moved(estimate, offset_m, control_steps_m):
    """The estimate with every offset moved by offset_m and control k translated by control_steps_m[k] along y."""
    corrections = tuple(c.compose(gtsam.Pose3(gtsam.Rot3(), [0.0, s, 0.0])) for c, s in zip(estimate.corrections,
                                                                                            control_steps_m))
    return Estimate(estimate.offsets + offset_m, estimate.extrinsic, corrections)


def test_the_coarse_phase_judges_the_controls_by_their_median():
    start = Estimate(np.zeros((4, 4)), gtsam.Pose3(gtsam.Rot3.Yaw(0.1), [1.0, 0.0, 2.0]),
                     tuple(gtsam.Pose3() for _ in range(9)))
    # two controls the coarse pairs barely reach step 8 cm; the others 2 mm; the intrinsics 3 mm
    steps = np.r_[0.08, 0.08, np.full(7, 0.002)]
    moved = _moved(start, 0.003, steps)
    assert step_size(start, moved) == pytest.approx(0.08)
    assert step_size(start, moved, "coarse") == pytest.approx(0.003)
    # the median control itself decides once it is the largest
    assert step_size(start, _moved(start, 0.001, np.full(9, 0.02)), "coarse") == pytest.approx(0.02)
    # no controls (no trajectory estimated): the calibration's keys alone
    bare = Estimate(start.offsets, start.extrinsic, ())
    assert step_size(bare, Estimate(bare.offsets + 0.004, bare.extrinsic, ()), "coarse") == pytest.approx(0.004)


def _overshooting_graph():
    """x0 held at 0 by a HELD_SIGMA prior (information 1e14) and x1 with residual tanh(x1) - 0.5 at a
    sigma of 1e-6 from x1 = 3, where tanh is flat: the Gauss-Newton step (about -50) lands where the
    residual is larger (tanh = -1), and lambda must reach ~1e9 to shorten it enough."""
    def residual(_, values, jacobians):
        x = values.atVector(1)[0]
        if jacobians is not None:
            jacobians[0] = np.array([[1.0 - np.tanh(x) ** 2]])
        return np.array([np.tanh(x) - 0.5])

    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorVector(0, np.zeros(1), gtsam.noiseModel.Isotropic.Sigma(1, HELD_SIGMA)))
    graph.add(gtsam.CustomFactor(gtsam.noiseModel.Isotropic.Sigma(1, 1e-6), [1], residual))
    values = gtsam.Values()
    values.insert(0, np.zeros(1))
    values.insert(1, np.array([3.0]))
    return graph, values


def test_lm_steps_where_the_default_damping_cannot():
    graph, values = _overshooting_graph()
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(20)
    stuck = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    assert stuck.atVector(1)[0] == 3.0  # GTSAM's default: every lambda up to 1e5 rejected
    for assembled in (False, True):  # GTSAM's optimizer, and the same steps assembled
        solved = levenberg_marquardt(graph, values, 20, assembled)
        assert np.tanh(solved.atVector(1)[0]) == pytest.approx(0.5, abs=1e-9)
        assert solved.atVector(0)[0] == 0.0


def test_features_are_computed_again_only_when_the_cloud_changes_shape():
    from graphcal.calibration.config import CalibrationConfig
    from graphcal.calibration.pairing import FeatureCache, moved_m

    rng = np.random.default_rng(0)
    plane = np.column_stack([rng.uniform(0, 5, 2000), rng.uniform(0, 5, 2000), np.zeros(2000)])
    assert moved_m(plane + [3.0, -2.0, 0.5], plane, 0.5) == pytest.approx(0.0, abs=1e-12)  # a translation: nothing
    bent = plane.copy()
    bent[0, 2] += 0.002
    assert moved_m(bent, plane, 0.5) == pytest.approx(0.002, rel=0.01)  # one point off the plane by 2 mm
    # a turn of 1 mrad about the vertical moves the far corner by 3.5 mm but leaves the shape: it turns the
    # normals by 1 mrad, 0.5 mm over a 0.5 m neighbourhood
    turned = plane @ np.array([[np.cos(1e-3), -np.sin(1e-3), 0], [np.sin(1e-3), np.cos(1e-3), 0], [0, 0, 1]]).T
    assert moved_m(turned, plane, 0.5) == pytest.approx(0.5e-3, rel=1e-6)
    assert moved_m(plane, None, 0.5) == np.inf and moved_m(plane[:10], plane, 0.5) == np.inf

    cache = FeatureCache(CalibrationConfig(features={"refresh_above_m": 0.001}).for_sensor(False).features)
    features, computed = cache.at(plane)
    assert computed and np.allclose(np.abs(features.normal[:, 2]), 1.0)
    assert cache.at(plane + [0.0, 0.0, 0.3]) == (features, False)
    tilted = plane.copy()
    tilted[:, 2] = 0.01 * tilted[:, 0]  # a 0.57 deg tilt: up to 5 cm
    features, computed = cache.at(tilted)
    assert computed and np.allclose(np.abs(features.normal @ [-0.01, 0, 1]) / np.hypot(0.01, 1), 1.0)


def test_the_same_cloud_is_paired_once():
    """A weak-direction analysis and the solve after it pair the same cloud: the second gets the first's pairs;
    a cloud moved, another gate or other features are paired again."""
    from graphcal.calibration.association import PairCloud, associate, neighbour_fibres, PairGates
    from graphcal.calibration.config import FINE, CalibrationConfig
    from graphcal.calibration.pairing import Association, FeatureCache, features_at

    rng = np.random.default_rng(1)
    fibre = rng.integers(0, 3, 6000)
    points = np.column_stack([rng.uniform(0, 4, 6000), rng.uniform(0, 4, 6000), np.zeros(6000)])
    points[:, 2] = 0.002 * points[:, 0]  # three fibres' returns on one plane
    settings = CalibrationConfig().for_sensor(False).features
    made = []

    class Counted(Association):
        def pairs(self, *args):
            made.append(args[3])
            return super().pairs(*args)

    association = Counted(FINE, neighbour_fibres(np.array([0.0, 1.0, 2.0]), 1), np.arange(6000), 0)
    cache = FeatureCache(settings)
    features = cache.at(points)[0]
    first = cache.pairs(association, points, fibre, features, 0.3, lambda: None)
    expected = associate(PairCloud(points, fibre, features), association.neighbours, PairGates.of(FINE, 0.3),
                         np.random.default_rng(0), np.arange(6000))
    assert len(first) > 100 and np.array_equal(first.index_m, expected.index_m)
    assert cache.pairs(association, points.copy(), fibre, features, 0.3, lambda: None) is first and len(made) == 1
    cache.pairs(association, points, fibre, features, 0.2, lambda: None)
    cache.pairs(association, points + [0, 0, 1e-3], fibre, features, 0.2, lambda: None)
    cache.pairs(association, points + [0, 0, 1e-3], fibre, features_at(points, settings), 0.2, lambda: None)
    assert made == [0.3, 0.2, 0.2, 0.2]


def test_the_coarse_phase_sample_keeps_each_return_whole():
    from graphcal.calibration.returns import ReturnData
    from graphcal.recording.sensor import sensor_from_catalog

    rng = np.random.default_rng(3)
    n = 5000
    time_s = np.sort(rng.uniform(0, 3, n))
    control = np.minimum(time_s.astype(int), 2)
    data = ReturnData(sensor_from_catalog("HDL-32E"), np.arange(n) * 7, rng.integers(0, 32, n), rng.uniform(1, 50, n),
                      rng.uniform(0, 6.28, n), time_s, rng.normal(size=(n, 3, 3)), rng.normal(size=(n, 3)), control,
                      time_s - control, np.arange(4.0), np.zeros(3), 0.01)
    sample = data.sample(1000, np.random.default_rng(0))
    assert len(sample.rows) == 1000 and np.all(np.diff(sample.rows) > 0)
    k = sample.rows // 7  # the row of each sampled return in data
    for name in ("fibre", "range_m", "azimuth_rad", "time_s", "R_nav", "X_nav", "control", "alpha"):
        np.testing.assert_array_equal(getattr(sample, name), getattr(data, name)[k])
    assert sample.control_times_s is data.control_times_s and sample.sensor is data.sensor
    assert data.sample(n, np.random.default_rng(0)) is data


def test_the_fine_phase_averages_its_plateau_and_run_again_goes_on_from_its_j_curve(foreign_box_street):
    """A converged fine phase returns the mean of its last plateau_iterations outer iterations' estimates. Run again
    from there (as the end does once it holds more): given the first run's J curve it stops at its first outer
    iteration, whose step is below fine_below_m; started afresh, the plateau test needs plateau_iterations + 1
    energies of its own, and only a step below tolerance_m stops it sooner."""
    from graphcal.calibration.config import CalibrationConfig
    from graphcal.calibration.problem import History, Problem
    from graphcal.calibration.returns import initial_estimate
    from graphcal.recording.directory import Recording

    recording = Recording.load(foreign_box_street)
    problem = Problem.of(recording, CalibrationConfig(mode="joint", seed=0))
    stage = problem.stages[-1]
    problem, stopping = problem.in_stage(stage), problem.settings.stopping
    first, seen = History(), []
    converged = problem.fit(initial_estimate(recording, problem.full), first, stage,
                            after_each=lambda estimate, _, window: seen.append((estimate, window)))
    energies = tuple(row["energy_cm2"] for row in first.rows if row["phase"] == "fine")
    assert first.rows[-1]["stop"] == "converged" and len(energies) > stopping.plateau_iterations
    # converged: the mean of the last plateau_iterations fine iterations' estimates, the last one's in the window only
    window = seen[-1][1]
    assert len(window) == stopping.plateau_iterations
    assert all(a is b for a, (b, _) in zip(window[:-1], seen[-stopping.plateau_iterations:-1]))
    np.testing.assert_allclose(converged.offsets, np.mean([e.offsets for e in window], axis=0), rtol=0, atol=1e-15)
    turns = [window[-1].extrinsic.localCoordinates(e.extrinsic) for e in window]
    np.testing.assert_allclose(window[-1].extrinsic.localCoordinates(converged.extrinsic), np.mean(turns, axis=0),
                               rtol=1e-9, atol=1e-15)
    assert seen[-1][0] is converged or np.array_equal(seen[-1][0].offsets, converged.offsets)
    again = History()
    problem.fit(converged, again, stage, ("fine",), plateau_from=energies)
    assert len(again.rows) == 1 and again.rows[0]["stop"] == "converged"
    assert again.rows[0]["max_step"] < stopping.fine_below_m
    afresh = History()
    problem.fit(converged, afresh, stage, ("fine",), max_iterations=2)
    assert afresh.rows[0]["stop"] == "" or afresh.rows[0]["max_step"] < stopping.tolerance_m


def test_the_plateau_waits_for_the_window_to_stop_drifting(foreign_box_street):
    """calibration_sigmas against GTSAM's marginals on the pairs' factors and the priors (mode joint: no trajectory
    to marginalise); drifting: a window whose first and last estimates differ, for one kind of parameter, by a median
    above stopping.trend_sigmas of the sigmas drifts, whatever the signs; one that moved by less does not."""
    from dataclasses import replace

    from graphcal.calibration.config import CalibrationConfig
    from graphcal.calibration.keys import E, I
    from graphcal.calibration.problem import Problem
    from graphcal.calibration.returns import initial_estimate
    from graphcal.recording.directory import Recording

    recording = Recording.load(foreign_box_street)
    problem = Problem.of(recording, CalibrationConfig(mode="joint", seed=0))
    problem = problem.in_stage(problem.stages[-1]).in_phase("fine")
    estimate = initial_estimate(recording, problem.full)
    pairs = problem.associate(estimate)
    sigma = problem.calibration_sigmas(estimate, pairs)

    layout = problem.layout()
    graph, values = problem._pairs_graph(estimate, pairs)
    for f in layout.fibres:
        graph.add(gtsam.PriorFactorVector(I(f), estimate.offsets[f], gtsam.noiseModel.Diagonal.Sigmas(
            problem.priors.intrinsic[f])))
    graph.add(gtsam.PriorFactorPose3(E(0), estimate.extrinsic, problem.priors.extrinsic_noise(
        problem.nominal.rotation().matrix())))
    marginals = gtsam.Marginals(graph, values)
    expected = np.concatenate([np.sqrt(np.diag(marginals.marginalCovariance(key)))
                               for key in problem.calibration_keys()])
    np.testing.assert_allclose(sigma, expected, rtol=1e-6)

    trend = problem.settings.stopping.trend_sigmas
    fibres = list(layout.fibres)
    signs = np.where(np.arange(len(fibres)) % 2, 1.0, -1.0)

    def moved(elevation_sigmas=0.0, lever_arm_sigmas=0.0):
        offsets = estimate.offsets.copy()
        offsets[fibres, 2] += elevation_sigmas * signs * sigma[:4 * len(fibres)].reshape(-1, 4)[:, 2]
        lever_arm = lever_arm_sigmas * sigma[-3:]
        return replace(estimate, offsets=offsets, extrinsic=estimate.extrinsic.retract(np.r_[np.zeros(3), lever_arm]))

    assert problem.drifting((estimate, moved(elevation_sigmas=1.2 * trend)), sigma)
    assert problem.drifting((estimate, moved(lever_arm_sigmas=1.2 * trend)), sigma)
    assert not problem.drifting((estimate, moved(elevation_sigmas=0.8 * trend, lever_arm_sigmas=0.8 * trend)), sigma)
    assert not problem.drifting((estimate, estimate), sigma)
