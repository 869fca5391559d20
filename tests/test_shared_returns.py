"""The shared-returns covariance (graphcal/calibration/shared_returns.py) against independent math:
with no return shared it is the Marginals' covariance, and over fresh range-noise draws on fixed
pairs it is the spread of the estimate's Gauss-Newton step, where the Marginals are optimistic; over draws of
the error smoothing leaves in the poses, its shared-poses part is that step's spread; and
the pair model it rests on: without noise, the step at the truth is small once each pair's sigma holds
its plane-model error."""

from dataclasses import replace

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

import factors.point_to_plane
import graphcal
from graphcal.calibration.config import ESTIMATES, CalibrationConfig
from graphcal.calibration.keys import I
from graphcal.calibration.observability import (
    INTRINSIC_NAMES,
    FactorisedMarginals,
    Meat,
    information_of,
    tangent_widths,
)
from graphcal.calibration.priors import Priors
from graphcal.calibration.problem import Problem
from graphcal.calibration.result import SIGMA_SHARED, SIGMA_WIDENED
from graphcal.calibration.returns import initial_estimate, prepare
from graphcal.calibration.shared_returns import Linearised, shared_poses_meat, shared_returns_covariance
from graphcal.recording.trajectory_noise import PoseNoise
from graphcal.simulation.script import load_scenario_builder
from graphcal.simulation.starts import FAR_START_PRIORS

RANGE_NOISE_M = 0.01
INTRINSIC = ESTIMATES["intrinsic"]


@pytest.fixture(scope="module")
def at_truth():
    """A noise-free street (size 0.02), the settings of a head with 1 cm range noise (stand-ins,
    pairs whitened along their lines of sight), the true calibration and the strict pairs there."""
    recording = graphcal.simulate(load_scenario_builder("sim2_street")(size=0.02, seed=4), quiet=True)
    data = prepare(recording, 1.0)
    config = CalibrationConfig(mode="intrinsic", weighting={"sigma0_m": RANGE_NOISE_M, "range_noise_m": RANGE_NOISE_M},
                               priors=FAR_START_PRIORS)  # the truth is Table 4.1's, far from the nominal
    config = config.for_sensor(data.static, np.nan)
    assert config.weighting.pair_noise == "incidence"
    truth = replace(initial_estimate(recording, data), offsets=recording.truth.intrinsics)
    problem = Problem(data, config, INTRINSIC, truth.extrinsic,
                      Priors.of(config, data.sensor.n_fibres, len(data.control_times_s)))
    problem = problem.holding(config.priors.gauges(data.sensor.reference_fibre))  # as Problem.of holds them
    return problem, truth, problem.associate(truth)


def test_the_plane_model_term_takes_the_edges_bias_out_of_the_step_at_the_truth(at_truth):
    """A noise-free cloud with a noisy head's settings: the Gauss-Newton step at the true calibration is
    what the pair model alone gets wrong. Voxel normals tilt near edges and the pairs there pull the
    offsets (docs/reference/math.md "Observability"); with each pair's out-of-plane scatter in its sigma the step
    is several times smaller for every parameter type (measured: 6x to 13x)."""
    problem, truth, pairs = at_truth
    sensor = problem.data.sensor

    def rms_step(pairs_used) -> np.ndarray:
        graph, values = problem.graph(truth, pairs_used, damped=False)
        step = graph.linearize(values).optimize()
        fibres = [f for f in range(sensor.n_fibres) if f != sensor.reference_fibre]
        return np.sqrt((np.array([step.at(I(f)) for f in fibres]) ** 2).mean(axis=0))

    assert pairs.out_of_plane_m is not None and np.all(pairs.out_of_plane_m >= 0)
    with_term, without = rms_step(pairs), rms_step(replace(pairs, out_of_plane_m=None))
    assert np.all(with_term < without / 3)


def test_without_shared_returns_it_is_the_marginals(at_truth):
    """Pairs that share no return, unit weights: each pair's residual carries its own noise, as the
    Marginals assume, so both covariances agree (up to the weak priors, which only lower the sandwich)."""
    problem, truth, pairs = at_truth
    used, alone = set(), np.zeros(len(pairs), bool)
    for k, (p, m) in enumerate(zip(pairs.index_p.tolist(), pairs.index_m.tolist())):
        if p not in used and m not in used:
            used |= {p, m}
            alone[k] = True
    assert alone.sum() > 3000
    lone = replace(pairs.take(alone), weight=np.ones(alone.sum()))
    fit = problem.final(truth, lone, shared_returns=True)
    estimated = ~np.isnan(fit.uncertainty.intrinsics).all(axis=1)
    marginal, shared = fit.uncertainty.intrinsics[estimated], fit.shared_returns.intrinsics[estimated]
    assert np.all(shared <= marginal * (1 + 1e-9))
    determined = marginal < 0.2 * fit.uncertainty.intrinsics_prior[estimated]
    assert determined.mean() > 0.9
    np.testing.assert_allclose(shared[determined], marginal[determined], rtol=0.03)


def test_it_is_the_spread_of_the_estimate_over_range_noise_draws(at_truth, monkeypatch):
    """Fresh 1 cm range noise on every return, the same pairs: the Gauss-Newton step at the truth
    varies over the draws as the shared-returns covariance says (the pairs' sigma left without the
    floor for the model's other errors, which no draw here makes), and not as the Marginals say: the
    pairs share returns. Judged by the mean over the draws of the step's squared Mahalanobis length
    (about the draws' mean) per parameter, 1 when the covariance is right, within 3.8 % at 12 draws of
    124 parameters (60 draws: 0.98 with the sandwich, 2.4 with the Marginals)."""
    monkeypatch.setattr(factors.point_to_plane, "INCIDENCE_FLOOR", 0.0)
    problem, truth, pairs = at_truth
    data = problem.data
    blocks = problem.blocks(truth, pairs)
    graph, values = problem.graph(truth, pairs, damped=False, blocks=blocks)
    keys = [I(f) for f in range(data.sensor.n_fibres) if f != data.sensor.reference_fibre]
    rng = np.random.default_rng(11)
    steps = []
    for _ in range(12):
        noisy = replace(data, range_m=data.range_m + rng.normal(0.0, RANGE_NOISE_M, len(data.range_m)))
        graph_d, values_d = replace(problem, full=noisy, data=noisy).graph(truth, pairs, damped=False)
        step = graph_d.linearize(values_d).optimize()
        steps.append(np.concatenate([step.at(key) for key in keys]))
    shared = shared_returns_covariance(Linearised.of(graph, values, blocks, len(pairs)), pairs, data, truth, RANGE_NOISE_M)
    assert abs(_mahalanobis_per_parameter(steps, shared, keys) - 1) < 0.1
    assert _mahalanobis_per_parameter(steps, FactorisedMarginals(graph, values), keys) > 1.5


def _mahalanobis_per_parameter(steps: list[np.ndarray], covariance, keys) -> float:
    """Mean squared Mahalanobis length of the steps about their mean, per parameter: 1 when the covariance is
    their spread."""
    deviation = np.array(steps) - np.mean(steps, axis=0)
    joint = np.block([[covariance.jointCovariance(a, b) for b in keys] for a in keys])
    eigenvalues, vectors = np.linalg.eigh(joint)
    lengths = ((deviation @ vectors) ** 2 / eigenvalues).sum(axis=1)
    return float(lengths.sum() / (len(deviation) - 1) / joint.shape[0])


def test_the_shared_poses_term_is_the_spread_of_the_estimate_over_pose_error_draws(at_truth):
    """An error of 2 mm and 0.004 deg per axis on the poses, one draw per 50 ms window (what smoothing leaves in a
    noisy INS's poses, ReturnData.smoothing_error), the same pairs: the Gauss-Newton step at the truth varies over
    the draws as H^-1 (shared poses' meat) H^-1 says, the returns of one window moved together by dX + e x (p - X).
    Within 12 % at 12 draws of 124 parameters (measured 1.06)."""
    problem, truth, pairs = at_truth
    error = PoseNoise(0.002, np.radians(0.004), 0.05)
    data = replace(problem.data, smoothing_error=error)
    blocks = problem.blocks(truth, pairs)
    graph, values = problem.graph(truth, pairs, damped=False, blocks=blocks)
    keys = [I(f) for f in range(data.sensor.n_fibres) if f != data.sensor.reference_fibre]
    window = np.floor((data.time_s - data.time_s.min()) / error.interval_s).astype(int)
    rng = np.random.default_rng(13)
    steps = []
    for _ in range(12):
        moved = rng.normal(0.0, error.position_m, (window.max() + 1, 3))[window]
        turned = Rotation.from_rotvec(rng.normal(0.0, error.attitude_rad, (window.max() + 1, 3))[window]).as_matrix()
        drawn = replace(data, X_nav=data.X_nav + moved, R_nav=turned @ data.R_nav)
        graph_d, values_d = replace(problem, full=drawn, data=drawn).graph(truth, pairs, damped=False)
        step = graph_d.linearize(values_d).optimize()
        steps.append(np.concatenate([step.at(key) for key in keys]))
    linearised = Linearised.of(graph, values, blocks, len(pairs))
    covariance = linearised.bread.sandwich(Meat(shared_poses_meat(linearised, pairs, data, truth)))
    assert abs(_mahalanobis_per_parameter(steps, covariance, keys) - 1) < 0.12
    assert not shared_poses_meat(linearised, pairs, problem.data, truth).count_nonzero()  # nothing left: no term


def test_calibrate_reports_the_shared_returns_sigmas_for_a_noisy_head(tmp_path):
    """A head with 1 cm range noise: calibrate keeps the three covariances and calibration.yaml writes the
    shared-returns sigmas (not the Marginals': the pairs share returns, and their own parts are smaller
    than the Marginals assume), each widened to the cluster-robust one where that is larger, and says so in its
    provenance."""
    recording = graphcal.simulate(load_scenario_builder("sim2_street")(size=0.05, seed=1, range_noise_m=0.01),
                                  quiet=True)
    result = graphcal.calibrate(recording, CalibrationConfig(mode="intrinsic", priors=FAR_START_PRIORS, stopping={
        "max_outer_iterations": 8, "refuse_unconverged": False}),
                                quiet=True)
    assert result.config.weighting.pair_noise == "incidence"
    shared, marginal = result.shared_returns_uncertainty.intrinsics, result.uncertainty.intrinsics
    free = np.array([[f"fibre_{f}.{name}" not in result.unobservable and f != recording.sensor.reference_fibre
                      for name in INTRINSIC_NAMES] for f in range(len(shared))])
    assert free.mean() > 0.9
    assert np.all(shared[free] > 0)
    assert np.median(np.abs(shared[free] / marginal[free] - 1)) > 0.01
    written = yaml.safe_load(result.save(tmp_path).read_text())
    robust = result.cluster_robust_uncertainty
    reported = shared if robust is None else np.fmax(shared, robust.intrinsics)
    assert written["provenance"]["sigma"] == SIGMA_SHARED + ("" if robust is None else SIGMA_WIDENED)
    prior = result.uncertainty.intrinsics_prior
    for row in written["intrinsics"]:
        fibre = row["fibre"]
        for k, name in enumerate(INTRINSIC_NAMES):
            if free[fibre, k]:  # at least the nominal's error along the weak directions held (a share s of it)
                held = np.sqrt(result.held_shares.get(f"fibre_{fibre}.{name}", 0.0)) * prior[fibre, k]
                assert row["sigma"][name] == pytest.approx(max(reported[fibre, k], held))


def test_without_pairs_the_estimate_carries_no_range_noise(at_truth):
    """No pair: the priors alone fix the estimate, and no return's noise reaches it: its covariance is the
    priors' (the nominal value is off by the prior's sigma)."""
    problem, truth, pairs = at_truth
    data, priors = problem.data, problem.priors
    none = pairs.take(np.zeros(0, np.int64))
    blocks = problem.blocks(truth, none)
    graph, values = problem.graph(truth, none, damped=False, blocks=blocks)
    covariance = shared_returns_covariance(Linearised.of(graph, values, blocks, len(none)), none, data, truth, RANGE_NOISE_M)
    assert not blocks
    prior = priors.intrinsic[0 if data.sensor.reference_fibre else 1]
    np.testing.assert_allclose(covariance.marginalCovariance(I(0 if data.sensor.reference_fibre else 1)),
                               np.diag(prior ** 2), rtol=1e-9, atol=1e-20)


def test_the_bread_from_the_pairs_jacobian_is_the_graph_s_own_information(at_truth):
    """H = A^T A + P (the pairs' whitened Jacobian, the prior factors' information) equals the information of the
    graph GTSAM linearises (its blocks compressed by factors.point_to_plane.compress), to rounding; so does the
    path that linearises the blocks themselves (taken when a robust loss reweights them)."""
    problem, truth, pairs = at_truth
    blocks = problem.blocks(truth, pairs)
    graph, values = problem.graph(truth, pairs, damped=False, blocks=blocks)
    whole = information_of(graph, values, tangent_widths(values)).toarray()
    for robust in (False, True):
        H = Linearised.of(graph, values, blocks, len(pairs), robust).bread.information.toarray()
        np.testing.assert_allclose(H, whole, rtol=1e-6, atol=1e-9 * np.abs(whole).max())
