"""Score tests of candidate effects (graphcal.diagnosis.score) on linear problems whose answer is
known: estimate, false-alarm rate under correlated noise, MDB, concealment and the absorbing
parameter against independent least squares."""

import numpy as np
import pytest
from scipy import stats

from graphcal.diagnosis.score import (
    PRACTICAL_FLOOR_SIGMA0,
    linearisation_of_rows,
    noncentrality,
    score_candidate,
    wald_at_refit,
)

K_ROWS, CLUSTERS = 2000, 200


def _problem(rng, theta_true: float, shared_sigma: float = 0.0, noise_sigma: float = 1.0, base=(0.3, -0.2)):
    """Residuals r = -(A0 a + a_k theta) + noise: base columns x0, x1 (x1 correlated with the
    candidate's column), the candidate k; noise with a part shared by each cluster of 10 rows."""
    x = rng.normal(size=(K_ROWS, 3))
    A = np.column_stack([x[:, 0], x[:, 1], 0.8 * x[:, 1] + 0.6 * x[:, 2]])
    cluster = np.repeat(np.arange(CLUSTERS), K_ROWS // CLUSTERS)
    noise = noise_sigma * rng.normal(size=K_ROWS) + shared_sigma * rng.normal(size=CLUSTERS)[cluster]
    r = -(A @ np.array([*base, theta_true])) + noise  # at the linearisation point every parameter is 0
    return linearisation_of_rows(r, A, ["x0", "x1", "range_scale"], {"range_scale": np.array([2])}, cluster, cluster, 0.01), A, r


def test_estimate_sigma_concealment_and_absorbing_parameter():
    rng = np.random.default_rng(0)
    lin, A, r = _problem(rng, theta_true=0.5)
    test = score_candidate(lin, "range_scale", ["range_scale"])
    full, *_ = np.linalg.lstsq(A, -r, rcond=None)  # independent least squares on all three
    assert test.theta[0] == pytest.approx(full[2], rel=1e-9)
    residual = A[:, 2] - A[:, :2] @ np.linalg.lstsq(A[:, :2], A[:, 2], rcond=None)[0]
    assert test.concealment_r2 == pytest.approx(1 - residual @ residual / (A[:, 2] @ A[:, 2]), rel=1e-9)
    assert test.absorbed_by[0][0] == "x1" and test.absorbed_by[0][1] < -0.5
    assert abs(test.magnitude - 0.5) < 4 * test.sigma and test.p_value < 1e-10
    assert test.held_out_cm2[1] < test.held_out_cm2[0]


def test_held_out_drop_and_its_standard_error_match_a_fit_on_each_half():
    """Independent least squares on each half's rows (the linear problem has no prior), evaluated fold by fold
    (time blocks modulo FOLDS) on the other half: the held-out J of both models and the ratio estimator's standard
    error of their drop."""
    from graphcal.diagnosis.score import FOLDS

    rng = np.random.default_rng(3)
    lin, A, r = _problem(rng, theta_true=0.05, shared_sigma=0.5)
    test = score_candidate(lin, "range_scale", ["range_scale"])
    cluster = np.repeat(np.arange(CLUSTERS), K_ROWS // CLUSTERS)
    held, variance = np.zeros(2), 0.0
    for h in (0, 1):
        fit, out = cluster % 2 == h, cluster % 2 != h
        cost = []
        for columns in ([0, 1], [0, 1, 2]):
            step, *_ = np.linalg.lstsq(A[fit][:, columns], -r[fit], rcond=None)
            cost.append((r[out] + A[out][:, columns] @ step) ** 2)
        held += [c.sum() / out.sum() * 0.01 ** 2 * 1e4 / 2 for c in cost]
        fold = cluster[out] % FOLDS
        drop = np.bincount(fold, weights=cost[0] - cost[1], minlength=FOLDS)[fold.min()::2]
        weight = np.bincount(fold, minlength=FOLDS)[fold.min()::2].astype(float)
        ratio = drop.sum() / weight.sum()
        variance += np.sum((drop - ratio * weight) ** 2) / weight.sum() ** 2 * len(drop) / (len(drop) - 1)
    assert test.held_out_cm2 == pytest.approx(tuple(held), rel=1e-9)
    assert test.held_out_se_cm2 == pytest.approx(np.sqrt(variance) / 2 * 0.01 ** 2 * 1e4, rel=1e-9)


def test_the_refit_check_is_the_wald_statistic_of_the_re_solved_size():
    """At the refit the effect is estimated with the rest: v^T C^-1 v with the score test's robust
    covariance there; for this problem, theta fitted with everything by least squares."""
    rng = np.random.default_rng(4)
    lin, A, r = _problem(rng, theta_true=0.5)
    test = score_candidate(lin, "range_scale", ["range_scale"])
    value = np.linalg.lstsq(A, -r, rcond=None)[0][2:]  # the size re-solved with the others
    statistic, p_value = wald_at_refit(value, test)
    assert statistic == pytest.approx(value[0] ** 2 / test.covariance[0, 0], rel=1e-9)
    assert p_value == pytest.approx(stats.chi2.sf(statistic, 1), rel=1e-9) and p_value < 1e-10
    _, p_small = wald_at_refit(0.3 * np.sqrt(test.covariance[0, 0]) * np.ones(1), test)
    assert p_small == pytest.approx(2 * stats.norm.sf(0.3), rel=1e-9)  # 0.3 sigma: nothing


def test_lambda0_is_baardas():
    assert noncentrality(1) == pytest.approx(17.07, abs=0.01)


def test_false_alarms_stay_at_the_nominal_rate_with_correlated_noise():
    rng = np.random.default_rng(1)
    robust, naive = [], []
    for _ in range(300):
        test = score_candidate(_problem(rng, theta_true=0.0, shared_sigma=2.0)[0], "range_scale", ["range_scale"])
        robust.append(test.p_value)
        naive.append(stats.chi2.sf(test.naive_statistic, 1))
    assert np.mean(np.array(robust) < 0.05) < 0.10  # nominal 5 %
    assert np.mean(np.array(naive) < 0.05) > 0.3  # the textbook statistic counts correlated rows as independent


def test_an_effect_too_small_to_matter_is_not_a_finding_however_sure():
    """Noise-free data resolve any misfit: a candidate explaining 0.06 % of sigma0 has p ~ 0 but is not
    significant; the explained RMS is sigma0 |theta| times the RMS of its column projected off the base."""
    rng = np.random.default_rng(2)
    lin, A, _ = _problem(rng, theta_true=1e-3, noise_sigma=1e-6, base=(0.0, 0.0))  # a converged fit
    tiny = score_candidate(lin, "range_scale", ["range_scale"])
    projected = A[:, 2] - A[:, :2] @ np.linalg.lstsq(A[:, :2], A[:, 2], rcond=None)[0]
    assert tiny.explained_rms_m == pytest.approx(0.01 * 1e-3 * np.sqrt(np.mean(projected ** 2)), rel=1e-3)
    assert tiny.p_value < 1e-12 and tiny.held_out_cm2[1] < tiny.held_out_cm2[0]
    assert tiny.explained_rms_m < PRACTICAL_FLOOR_SIGMA0 * 0.01 and not tiny.significant(1)
    large = score_candidate(_problem(rng, theta_true=0.5)[0], "range_scale", ["range_scale"])
    assert large.explained_rms_m > PRACTICAL_FLOOR_SIGMA0 * 0.01 and large.significant(1)


def test_twins_are_named_by_the_cost_they_explain_not_by_their_robust_factor():
    """Of two candidates the data cannot tell apart, the leader by robust statistic (time_offset, 100)
    explains less cost (naive 200) than its twin (spin_rate, naive 220, robust 90: a larger variance
    factor, itself an estimate): the twin takes the name, on the leader's factor (220 / 2 > 200 / 2).
    A candidate whose physics fixes its size (intra_sweep_motion) goes first whatever its cost."""
    from dataclasses import replace

    from graphcal.diagnosis.diagnose import name_preference

    test = score_candidate(_problem(np.random.default_rng(3), theta_true=0.5)[0], "range_scale", ["range_scale"])
    leader = replace(test, name="time_offset", statistic=100.0, naive_statistic=200.0)
    twin = replace(test, name="spin_rate", statistic=90.0, naive_statistic=220.0)
    sized = replace(test, name="intra_sweep_motion", statistic=50.0, naive_statistic=100.0)
    assert max([leader, twin], key=lambda t: name_preference(t, leader, None)) is twin
    assert max([leader, twin, sized], key=lambda t: name_preference(t, leader, None)) is sized
    assert name_preference(twin, leader, None)[1] == pytest.approx(220.0 / 2.0 - np.log(CLUSTERS))


def test_a_diagnosis_too_short_for_the_held_out_check_says_nothing_can_be_confirmed():
    from graphcal.diagnosis.diagnose import Diagnosis

    rows = [{"effect": "range_scale", "mdb": 1e-6, "magnitude": 1.0, "significant": False, "plausible": False,
             "held_out_se_cm2": float("inf")}]
    diagnosis = Diagnosis([], [], [], [], rows, [], {"before": 1.0}, 1.0)
    assert diagnosis.summary().startswith("nothing can be confirmed") and "ppm" not in diagnosis.summary()
    rows[0]["held_out_se_cm2"] = 0.01
    assert "MDB" in Diagnosis([], [], [], [], rows, [], {"before": 1.0}, 1.0).summary()
