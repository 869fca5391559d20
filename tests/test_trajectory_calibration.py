"""Trajectory corrections (seed 001) on a reduced sim6_turn, checked against the simulator's truth.

The full-size figures (seed: cloud-to-cloud 13.36 cm -> 6 mm) are in benchmarks/bench_calibrate.py.
The trajectory's common translation (and, with pose corrections, common rotation) is a gauge the
data cannot see: it is named unobservable, and the cloud is compared with truth once it is removed.
"""

from pathlib import Path

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


@pytest.mark.parametrize("large_from", [10 ** 9, 0])  # GTSAM's partial elimination; LAPACK on the dense H
def test_the_controls_marginalised_out_as_a_dense_schur_complement(piecewise_error, monkeypatch, large_from):
    """Problem.information eliminates the trajectory corrections from the sparse graph (GTSAM's partial
    elimination), or from the assembled dense H where the graph is large and nearly dense: it must equal the
    Schur complement of the dense information over every key."""
    import gtsam

    from graphcal.calibration import observability
    from graphcal.calibration.keys import X

    monkeypatch.setattr(observability, "LARGE_FROM", large_from)
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


def test_the_coarse_phase_on_every_third_control_places_the_returns_as_every_control_does(piecewise_error):
    """trajectory.coarse_max_controls: the coarse phase's keys are every k-th control and the last; corrections
    linear between those knots place every return where the same corrections at every control place it, and
    going to the knots and back changes nothing."""
    import gtsam

    from graphcal.calibration.problem import Problem
    from graphcal.calibration.returns import initial_estimate, knots_every

    config = graphcal.CalibrationConfig(mode="trajectory", trajectory={"coarse_max_controls": 3})
    problem = Problem.of(piecewise_error, config)
    n = len(problem.full.control_times_s)
    assert n == 7 and knots_every(n, 3).tolist() == [0, 3, 6] and knots_every(n, 7) is None
    assert knots_every(8, 3).tolist() == [0, 4, 7]
    coarse = problem.in_phase("coarse").on_coarse_controls()
    assert coarse.knots.tolist() == [0, 3, 6] and len(coarse.data.control_times_s) == 3
    assert problem.in_phase("coarse").knots is None and coarse.in_phase("fine").knots is None
    rng = np.random.default_rng(2)
    knot_poses = [gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(0, 0.01, 3)), rng.normal(0, 0.3, 3)) for _ in range(3)]
    on_knots = initial_estimate(piecewise_error, problem.full)
    on_knots = type(on_knots)(on_knots.offsets, on_knots.extrinsic, tuple(knot_poses))
    everywhere = coarse.at_every_control(on_knots)
    assert len(everywhere.corrections) == 7
    for k, c in zip([0, 3, 6], knot_poses):
        assert everywhere.corrections[k].equals(c, 1e-12)
    assert all(a.equals(b, 1e-12) for a, b in zip(coarse.own(everywhere).corrections, knot_poses))
    fine = problem.in_phase("coarse")  # the same returns at every control
    np.testing.assert_allclose(coarse.points(on_knots), fine.points(everywhere), atol=1e-9)
    assert not np.allclose(fine.points(everywhere), fine.points(initial_estimate(piecewise_error, problem.full)))


@pytest.fixture(scope="module")
def three_second_error():
    """sim6_turn with a position error piecewise linear between knots 3 s apart."""
    from graphcal.simulation.scenario import InsErrors

    return graphcal.simulate(SIM6(size=0.02, seed=4).model_copy(
        update={"ins": InsErrors(piecewise_error_m=0.35, piecewise_interval_s=3.0)}), quiet=True)


ON_THREE = graphcal.CalibrationConfig(mode="trajectory", trajectory={"coarse_max_controls": 3},
                                      stopping={"max_outer_iterations": 20})


def test_translation_corrections_from_a_coarse_phase_on_three_controls(three_second_error):
    """The coarse phase on every third control (which can follow the error), the fine phase on all: the error
    removed as the default removes it."""
    recording = three_second_error
    result = graphcal.calibrate(recording, ON_THREE, quiet=True)
    assert [row["phase"] for row in result.history].count("coarse") >= 2
    evaluation = graphcal.evaluate(result, recording)
    assert evaluation.cloud_before.mean > 0.10 and evaluation.cloud_after_gauge_free.mean < 0.006, evaluation.table()


def test_a_coarse_phase_on_knots_interrupted_resumes_to_the_uninterrupted_result(three_second_error, tmp_path,
                                                                                monkeypatch):
    """The checkpoint holds corrections at every control: stopped at the coarse phase's second outer iteration
    (on three knots) and resumed, the same outer iterations and corrections."""
    from graphcal.calibration.checkpoint import Checkpoint

    whole = graphcal.calibrate(three_second_error, ON_THREE, quiet=True)
    path, save = tmp_path / "checkpoint.npz", Checkpoint.save

    def stopping(self, state):
        save(self, state)
        if state.inside == (0, 2):
            assert len(state.estimate.corrections) == 7 and state.rows[-1]["phase"] == "coarse"
            raise KeyboardInterrupt

    monkeypatch.setattr(Checkpoint, "save", stopping)
    with pytest.raises(KeyboardInterrupt):
        graphcal.calibrate(three_second_error, ON_THREE, quiet=True, checkpoint=path)
    monkeypatch.setattr(Checkpoint, "save", save)
    resumed = graphcal.calibrate(three_second_error, ON_THREE, quiet=True, checkpoint=path)
    assert [(row["phase"], row["stop"]) for row in resumed.history] == [(row["phase"], row["stop"])
                                                                        for row in whole.history]
    for a, b in zip(resumed.calibration.estimate.corrections, whole.calibration.estimate.corrections):
        assert a.equals(b, 1e-7)


def test_a_checkpoint_with_other_controls_is_refused(three_second_error, tmp_path, monkeypatch):
    """A checkpoint whose trajectory has another number of controls than the calibration resuming it (written by
    a graphcal that placed its controls otherwise, here: one without the controls about a step of the INS) is
    refused with a ConfigError naming the file, not resumed."""
    import graphcal.calibration.returns as returns
    from graphcal.calibration.checkpoint import Checkpoint
    from graphcal.common.errors import ConfigError

    path, save = tmp_path / "checkpoint.npz", Checkpoint.save

    def stopping(self, state):
        save(self, state)
        raise KeyboardInterrupt

    monkeypatch.setattr(Checkpoint, "save", stopping)
    with pytest.raises(KeyboardInterrupt):
        graphcal.calibrate(three_second_error, ON_THREE, quiet=True, checkpoint=path)
    monkeypatch.setattr(Checkpoint, "save", save)
    span = three_second_error.world.poses.span
    monkeypatch.setattr(returns, "position_steps", lambda poses: np.array([[span[0] + 2.5, span[0] + 2.51]]))
    with pytest.raises(ConfigError, match=f"{path.name}: a checkpoint of another calibration: "
                                          r"trajectory controls 7 \(now 9\)"):
        graphcal.calibrate(three_second_error, ON_THREE, quiet=True, checkpoint=path)


def test_the_assembled_levenberg_marquardt_takes_gtsams_steps(piecewise_error):
    """On a joint calibration graph with trajectory corrections (coarse pairs at the start, where the steps are
    large and lambda changes), LAPACK's solves of the assembled system take GTSAM's steps, iteration by
    iteration; key_density counts the entries of H its factors reach."""
    import gtsam

    from graphcal.calibration.levenberg_marquardt import levenberg_marquardt
    from graphcal.calibration.observability import key_density, tangent_widths
    from graphcal.calibration.problem import Problem
    from graphcal.calibration.returns import initial_estimate

    problem = Problem.of(piecewise_error, graphcal.CalibrationConfig(mode="joint_trajectory"))
    problem = problem.in_stage(problem.stages[-1]).in_phase("coarse")
    estimate = initial_estimate(piecewise_error, problem.full)
    graph, values = problem.graph(estimate, problem.associate(estimate))
    widths = tangent_widths(values)
    H, _ = graph.linearize(values).hessian(gtsam.Ordering(list(widths)))
    edges = np.cumsum([0] + list(widths.values()))
    reached = sum((edges[i + 1] - edges[i]) * (edges[j + 1] - edges[j]) for i in range(len(widths))
                  for j in range(len(widths)) if np.any(H[edges[i]:edges[i + 1], edges[j]:edges[j + 1]]))
    assert key_density(graph, widths) == pytest.approx(reached / H.size, rel=1e-12)
    start = graph.error(values)
    for iterations in (1, 2, 5):
        ours = levenberg_marquardt(graph, values, iterations, assembled=True)
        gtsams = levenberg_marquardt(graph, values, iterations, assembled=False)
        assert graph.error(ours) == pytest.approx(graph.error(gtsams), rel=1e-12) and graph.error(ours) < start
        for key in widths:
            step = gtsams.localCoordinates(ours).at(key)
            assert np.abs(step).max() < 1e-9, (iterations, key, step)


@pytest.mark.parametrize("deformation", ["prior", "monnier"])
def test_e_def_on_knots_is_the_controls_e_def(piecewise_error, deformation):
    """On knots, E_def's terms are those of the controls they stand for: Monnier's successive differences exactly
    for corrections linear between knots (each knot difference spread over its gap), the priors (eq. 5.3's, or
    Monnier's anchors) exactly for a correction common to the whole drive (the gauge they hold)."""
    import gtsam

    from graphcal.calibration.problem import Problem, control_prior_sigma
    from graphcal.calibration.returns import initial_estimate

    config = graphcal.CalibrationConfig(mode="trajectory", trajectory={"coarse_max_controls": 3,
                                                                       "deformation": deformation})
    every = Problem.of(piecewise_error, config)
    knots = every.in_phase("coarse").on_coarse_controls()
    rng = np.random.default_rng(5)
    common = [gtsam.Pose3(gtsam.Rot3(), rng.normal(0, 0.2, 3))] * 3
    varied = [gtsam.Pose3(gtsam.Rot3(), rng.normal(0, 0.2, 3)) for _ in range(3)]
    start = initial_estimate(piecewise_error, every.full)
    for poses in [common] + ([varied] if deformation == "monnier" else []):
        on_knots = type(start)(start.offsets, start.extrinsic, tuple(poses))
        errors = []
        for problem, estimate in ((knots, on_knots), (every, knots.at_every_control(on_knots))):
            graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
            problem._add_trajectory(graph, values, estimate, False, control_prior_sigma(problem.config, 1e5))
            kept = [graph.at(i) for i in range(graph.size())
                    if poses is common or isinstance(graph.at(i), gtsam.BetweenFactorPoint3)]
            errors.append(sum(factor.error(values) for factor in kept))
        assert errors[1] > 0 and errors[0] == pytest.approx(errors[1], rel=1e-9), errors


@pytest.mark.parametrize("deformation", ["prior", "monnier"])
def test_a_stretch_the_data_do_not_see_follows_its_neighbours_under_monnier(piecewise_error, deformation):
    """Controls 0-1 and 5-6 pinned by stand-ins for their data (tight priors at an INS error of 5 cm in x, 5 sigmas),
    the three between left to E_def alone: Monnier's differences carry the neighbours' correction across them (the
    along-track corrections of a straight street the data barely see; their anchors, of sigma sqrt(7), pull them
    back by less than a quarter on these seven controls, by less on a longer drive), the seed's eq. 5.3 pulls each
    to zero (the INS's value). A 30 cm step between two pinned controls costs Huber's linear price, not the
    square."""
    import gtsam

    from graphcal.calibration.keys import X
    from graphcal.calibration.problem import JUMP_HUBER, Problem, control_prior_sigma
    from graphcal.calibration.returns import initial_estimate

    problem = Problem.of(piecewise_error, graphcal.CalibrationConfig(mode="trajectory",
                                                                    trajectory={"deformation": deformation}))
    estimate = initial_estimate(piecewise_error, problem.full)
    sigma = control_prior_sigma(problem.config, 1e5)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    problem._add_trajectory(graph, values, estimate, False, sigma)
    n = len(estimate.corrections)
    assert n == 7
    error = np.array([0.05, 0.0, 0.0])
    for c in (0, 1, n - 2, n - 1):
        graph.add(gtsam.PriorFactorPoint3(X(c), error, gtsam.noiseModel.Isotropic.Sigma(3, 1e-5)))
    solved = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    middle = np.array([solved.atPoint3(X(c)) for c in range(2, n - 2)])
    assert sigma == pytest.approx(0.01)
    if deformation == "monnier":  # differences of sigma (below Huber's threshold), anchors of sigma sqrt(7)
        chain = np.array([[2.0, -1.0, 0.0], [-1.0, 2.0, -1.0], [0.0, -1.0, 2.0]]) + np.eye(3) / n
        expected = np.outer(np.linalg.solve(chain, [1.0, 0.0, 1.0]), error)
        assert expected[:, 0].min() > 0.75 * error[0]
    else:
        expected = np.zeros((3, 3))
    np.testing.assert_allclose(middle, expected, atol=1e-6)
    if deformation == "monnier":  # Huber: rho(r) = k |r| - k^2 / 2 beyond k sigmas
        values = gtsam.Values()
        for c in range(n):
            values.insert(X(c), np.array([0.3 if c >= 3 else 0.0, 0.0, 0.0]))
        step = 0.3 / sigma
        assert step > JUMP_HUBER
        assert sum(graph.at(i).error(values) for i in range(graph.size())
                   if isinstance(graph.at(i), gtsam.BetweenFactorPoint3)) == pytest.approx(
            JUMP_HUBER * step - JUMP_HUBER ** 2 / 2, rel=1e-9)


def test_e_def_ties_the_controls_about_a_step_by_minus_the_step(piecewise_error):
    """Between the two controls about a step of the INS (ReturnData.control_steps_m), E_def's difference is minus
    the recorded step: no cost when the corrections step by that; a mismatch costs the square, over the step's
    sigma and E_def's over one control interval together (no Huber loss: 30 cm is far beyond its threshold)."""
    from dataclasses import replace

    import gtsam

    from graphcal.calibration.keys import X
    from graphcal.calibration.problem import JUMP_HUBER, Problem, control_prior_sigma
    from graphcal.calibration.returns import initial_estimate

    problem = Problem.of(piecewise_error, graphcal.CalibrationConfig(mode="trajectory"))
    step_m, step_sigma_m = np.array([0.02, -0.03, 0.01]), 0.002
    into = np.zeros((len(problem.full.control_times_s), 3))
    into[4] = step_m
    problem = replace(problem, data=replace(problem.data, control_steps_m=into, step_sigma_m=step_sigma_m))
    estimate = initial_estimate(piecewise_error, problem.full)
    sigma = control_prior_sigma(problem.config, 1e5)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    problem._add_trajectory(graph, values, estimate, False, sigma)
    across = [graph.at(i) for i in range(graph.size()) if isinstance(graph.at(i), gtsam.BetweenFactorPoint3)
              and list(graph.at(i).keys()) == [X(3), X(4)]]
    assert len(across) == 1
    stepped = gtsam.Values()
    for c in range(len(into)):
        stepped.insert(X(c), -step_m if c >= 4 else np.zeros(3))
    assert across[0].error(stepped) == pytest.approx(0.0, abs=1e-12)
    off = gtsam.Values()
    for c in range(len(into)):
        off.insert(X(c), np.array([0.3, 0.0, 0.0]) - step_m if c >= 4 else np.zeros(3))
    tie_sigma = np.sqrt(sigma ** 2 + step_sigma_m ** 2)
    assert 0.3 / tie_sigma > JUMP_HUBER
    assert across[0].error(off) == pytest.approx(0.5 * (0.3 / tie_sigma) ** 2, rel=1e-9)


def test_corrections_step_where_the_ins_steps(capsys):
    """An INS whose position steps (GNSS-like jumps of 5 cm per axis, seeded) over sim6_turn's piecewise error: the
    steps are found where the truth has them (the recorded error changes by more than 1 cm between two samples),
    a control stands on each side of each, and the corrections follow the INS's error at every control,
    those about the steps included, as they do without steps (the test above; with the grid's controls alone the
    same drive's corrections end up to 21 cm off, 7.7 cm RMS over the INS's samples)."""
    from graphcal.recording.trajectory_steps import position_steps

    scenario = SIM6(size=0.02, seed=4)
    jumps = scenario.ins.model_copy(update={"jump_rate_hz": 1.0, "jump_m": 0.05})
    recording = graphcal.simulate(scenario.model_copy(update={"ins": jumps}), quiet=True)
    recorded, true = recording.world.poses, to_world(recording.truth.trajectory, recording.crs).poses
    true_error = true.interpolate(recorded.time)[0] - recorded.position_m
    stepped = np.flatnonzero(np.linalg.norm(np.diff(true_error, axis=0), axis=1) > 0.01)
    assert len(stepped) >= 2
    np.testing.assert_array_equal(position_steps(recorded), recorded.time[np.column_stack([stepped, stepped + 1])])
    config = graphcal.CalibrationConfig(mode="trajectory", stopping={"max_outer_iterations": 20})
    result = graphcal.calibrate(recording, config, quiet=True)
    times = result.calibration.control_times_s
    assert set(recorded.time[stepped]) | set(recorded.time[stepped + 1]) <= set(times)
    np.testing.assert_array_equal(result.ins_steps_s, position_steps(recorded))
    from types import SimpleNamespace

    from graphcal.cli.main import _print_calibration

    _print_calibration(SimpleNamespace(result=result, evaluation=None, folder=Path("run")))  # graphcal calibrate's
    printed = capsys.readouterr().out
    assert f"steps of the recorded positions: {len(stepped)} (a GNSS update's jump)" in printed
    assert "range noise none (below 1 micrometre)" in printed  # a noise-free simulation's, not 2e-12 mm
    written = result.to_yaml_dict("test")["ins_steps_s"]  # calibration.yaml, which the report reads
    np.testing.assert_array_equal(written, result.ins_steps_s)
    inside = (times >= recorded.span[0]) & (times <= recorded.span[1])
    error = (np.array([c.translation() for c in result.calibration.estimate.corrections])[inside]
             - (true.interpolate(times[inside])[0] - recorded.interpolate(times[inside])[0]))
    np.testing.assert_allclose(error - error.mean(axis=0), 0.0, atol=0.01)
