"""Trajectory corrections (seed 001) on a reduced sim6_turn, checked against the simulator's truth.

The full-size figures (seed: cloud-to-cloud 13.36 cm -> 6 mm) are in benchmarks/bench_calibrate.py.
The trajectory's common translation (and, with pose corrections, common rotation) is a gauge the
data cannot see: it is named unobservable, and the cloud is compared with truth once it is removed.
"""

import numpy as np
import pytest

import graphcal
from graphcal.recording.geodesy import to_world
from graphcal.simulation.script import load_scenario_builder

SIM6 = load_scenario_builder("sim6_turn")


@pytest.fixture(scope="module")
def piecewise_error():
    return graphcal.simulate(SIM6(size=0.02, seed=4), quiet=True)


def test_translation_corrections_remove_the_piecewise_error(piecewise_error):
    recording = piecewise_error
    result = graphcal.calibrate(recording, graphcal.CalibrationConfig(mode="trajectory", stopping={"max_outer_iterations": 20}),
                                quiet=True)
    assert result.unobservable == ("trajectory.common_translation",)
    evaluation = graphcal.evaluate(result, recording)
    assert evaluation.cloud_before.mean > 0.10 and evaluation.cloud_after_gauge_free.mean < 0.006, evaluation.table()
    # each control's correction is the INS error there, up to the common translation
    times = result.calibration.control_times_s
    inside = (times >= recording.world.poses.span[0]) & (times <= recording.world.poses.span[1])
    true_position, _ = to_world(recording.truth.trajectory, recording.crs).poses.interpolate(times[inside])
    recorded_position, _ = recording.world.poses.interpolate(times[inside])
    error = (np.array([c.translation() for c in result.calibration.estimate.corrections])[inside]
             - (true_position - recorded_position))
    assert np.abs(true_position - recorded_position).max() > 0.2
    np.testing.assert_allclose(error - error.mean(axis=0), 0.0, atol=0.01)


@pytest.mark.slow  # 40-55 s
def test_an_ins_heading_error_needs_pose_corrections():
    """A 0.5 deg INS heading error turns every scan about the vehicle: translation corrections can
    only make the cloud consistent by turning it as a whole (it stays centimetres off), pose
    corrections turn the scans back."""
    recording = graphcal.simulate(SIM6(size=0.02, seed=5, piecewise_error_m=0.0, heading_error_deg=0.5), quiet=True)
    after = {}
    for pose in (False, True):
        config = graphcal.CalibrationConfig(mode="trajectory", trajectory={"pose_corrections": pose},
                                            stopping={"max_outer_iterations": 15})
        result = graphcal.calibrate(recording, config, quiet=True)
        after[pose] = graphcal.evaluate(result, recording)
    assert after[False].cloud_before.mean > 0.05
    assert after[False].cloud_after_gauge_free.mean > 0.03, after[False].table()
    assert after[True].cloud_after_gauge_free.mean < 0.006, after[True].table()


def test_the_controls_marginalised_out_as_a_dense_schur_complement(piecewise_error):
    """Problem.information eliminates the trajectory corrections from the sparse graph (GTSAM's partial
    elimination): it must equal the Schur complement of the dense information over every key."""
    import gtsam

    from graphcal.calibration.keys import X
    from graphcal.calibration.problem import Problem, control_prior_sigma
    from graphcal.calibration.returns import initial_estimate

    problem = Problem.of(piecewise_error, graphcal.CalibrationConfig(mode="joint_trajectory"))
    problem = problem.in_stage(problem.stages[-1])
    estimate = initial_estimate(piecewise_error, problem.full)
    pairs, keys = problem.associate(estimate), problem.calibration_keys()
    got = problem.information(estimate, pairs, keys)
    graph, values = problem._pairs_graph(estimate, pairs)  # the same factors, every key dense
    problem._add_trajectory(graph, gtsam.Values(), estimate, False,
                            control_prior_sigma(problem.config, float(pairs.weight.sum())))
    present = set(graph.keys())
    reached = [key for key in keys if key in present]  # a fibre no pair reaches has no column in either
    controls = [X(c) for c in range(len(estimate.corrections))]
    H, _ = graph.linearize(values).hessian(gtsam.Ordering(reached + controls))
    zero = values.zeroVectors()
    n = H.shape[0] - sum(zero.at(key).size for key in controls)
    expected = H[:n, :n] - H[:n, n:] @ np.linalg.solve(H[n:, n:], H[n:, :n])
    assert len(controls) > 3 and np.abs(H[:n, n:]).max() > 0  # the controls do couple to the keys
    width = {key: zero.at(key).size for key in keys}
    starts = dict(zip(keys, np.cumsum([0] + [width[key] for key in keys])))
    columns = np.concatenate([starts[key] + np.arange(width[key]) for key in reached])
    np.testing.assert_allclose(got[np.ix_(columns, columns)], expected, rtol=1e-6, atol=1e-6 * np.abs(expected).max())
    assert np.count_nonzero(got) == np.count_nonzero(got[np.ix_(columns, columns)])
