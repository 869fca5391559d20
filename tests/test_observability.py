"""The sparse marginals (the fallback of gtsam.Marginals and the sandwiches' bread) agree with gtsam.Marginals where
both work, and with dense inverses."""

import gtsam
import numpy as np
import pytest

import scipy.sparse as sparse

from graphcal.calibration import observability
from graphcal.calibration.observability import Meat, ScaledSolver, FactorisedMarginals, soft_parameters


def test_sparse_marginals_match_gtsam():
    rng = np.random.default_rng(0)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    values.insert(1, gtsam.Pose3(gtsam.Rot3.Rodrigues(rng.normal(0, 0.3, 3)), rng.normal(0, 1, 3)))
    values.insert(2, rng.normal(0, 1, 3))
    values.insert(3, rng.normal(0, 1, 4))
    graph.add(gtsam.PriorFactorPose3(1, gtsam.Pose3(), gtsam.noiseModel.Diagonal.Sigmas(rng.uniform(0.1, 1, 6))))
    graph.add(gtsam.PriorFactorPoint3(2, np.zeros(3), gtsam.noiseModel.Isotropic.Sigma(3, 2.0)))
    values.insert(4, rng.normal(0, 1, 3))
    graph.add(gtsam.BetweenFactorPoint3(2, 4, np.ones(3), gtsam.noiseModel.Isotropic.Sigma(3, 1.0)))
    graph.add(gtsam.PriorFactorVector(3, np.zeros(4), gtsam.noiseModel.Gaussian.Covariance(np.diag([1, 2, 3, 4.0]) + 0.5)))
    reference, dense = gtsam.Marginals(graph, values), FactorisedMarginals(graph, values)
    for key in (1, 2, 3, 4):
        np.testing.assert_allclose(dense.marginalCovariance(key), reference.marginalCovariance(key), rtol=1e-9, atol=1e-12)


def test_a_sandwich_s_blocks_are_those_of_the_whole_product():
    rng = np.random.default_rng(2)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for key in (1, 2, 3):
        values.insert(key, rng.normal(0, 1, 3))
        graph.add(gtsam.PriorFactorPoint3(key, np.zeros(3), gtsam.noiseModel.Isotropic.Sigma(3, rng.uniform(0.1, 2))))
    graph.add(gtsam.BetweenFactorPoint3(1, 3, np.ones(3), gtsam.noiseModel.Isotropic.Sigma(3, 0.5)))
    bread = FactorisedMarginals(graph, values)
    root = rng.normal(size=(9, 9))
    sparse_part, low_rank = root @ root.T, rng.normal(size=(2, 9))
    meat = sparse_part + low_rank.T @ np.diag([0.5, -0.2]) @ low_rank
    H_inv = np.linalg.inv(bread.information.toarray())
    whole = H_inv @ meat @ H_inv
    sandwich = bread.sandwich(Meat(sparse.csr_matrix(sparse_part), ((low_rank[:1], 0.5), (low_rank[1:], -0.2))))
    for a in (1, 2, 3):
        for b in (1, 2, 3):
            np.testing.assert_allclose(sandwich.jointCovariance(a, b), whole[3 * (a - 1):3 * a, 3 * (b - 1):3 * b],
                                       rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(bread.marginalCovariance(2), H_inv[3:6, 3:6], rtol=1e-10)  # the bread unchanged


def test_sparse_marginals_keep_an_ill_scaled_direction():
    """Information from 1e14 (a 0.1 um constraint) down to 1e-6 (a 1 km prior), as a sharp
    intrinsic next to a lever arm held by its prior: the weak variance must survive."""
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    values.insert(1, np.zeros(3))
    values.insert(2, np.zeros(3))
    graph.add(gtsam.PriorFactorPoint3(1, np.zeros(3), gtsam.noiseModel.Isotropic.Sigma(3, 1e-7)))
    graph.add(gtsam.PriorFactorPoint3(2, np.zeros(3), gtsam.noiseModel.Isotropic.Sigma(3, 1e3)))
    graph.add(gtsam.BetweenFactorPoint3(1, 2, np.zeros(3), gtsam.noiseModel.Diagonal.Sigmas(np.array([1e-7, 1e-7, 1e9]))))
    reference, dense = gtsam.Marginals(graph, values), FactorisedMarginals(graph, values)
    for key in (1, 2):
        np.testing.assert_allclose(dense.marginalCovariance(key), reference.marginalCovariance(key), rtol=1e-6, atol=1e-20)


@pytest.mark.parametrize("dense_from", [0.0, 1.1])  # factorised dense, sparse
def test_the_scaled_solver_by_its_factor_or_by_eigenvalues_where_the_pivots_vanish(monkeypatch, dense_from):
    """A well-conditioned information with scales over 8 decades is solved exactly (its sparse factor); one
    where two parameters are seen only together (their columns alike: no pivot left for the second) is inverted
    along its eigen-directions with the unseen one's eigenvalue floored: a variance there beyond any other."""
    monkeypatch.setattr(observability, "DENSE_FROM", dense_from)
    rng = np.random.default_rng(1)
    X = rng.normal(size=(60, 40)) * np.logspace(-4, 4, 40)
    information = X.T @ X
    scale = np.outer(*(1 / np.sqrt(np.diag(information)),) * 2)  # compared on a unit diagonal, entry by entry
    solver = ScaledSolver(information)
    assert solver.factorised
    np.testing.assert_allclose(solver(np.eye(40)) / scale, np.linalg.inv(information * scale), atol=1e-9)
    given = information.copy()  # an ndarray, solved by its dense factor (no inverse), left as it was
    np.testing.assert_allclose(ScaledSolver(given, inverse=False)(np.eye(40)) / scale,
                               np.linalg.inv(information * scale), atol=1e-9)
    assert np.array_equal(given, information)
    X[:, 8] = 3.0 * X[:, 7]
    together = X.T @ X
    scale = np.outer(*(1 / np.sqrt(np.diag(together)),) * 2)
    eigenvalues, vectors = np.linalg.eigh(together * scale)
    floored = (vectors / np.maximum(eigenvalues, eigenvalues.max() * np.finfo(float).eps)) @ vectors.T
    solver = ScaledSolver(sparse.csc_matrix(together))
    assert not solver.factorised
    inverse = solver(np.eye(40)) / scale
    seen = np.r_[0:7, 9:40]  # entries with 7 or 8 carry rounding times the floored eigenvalue's inverse: O(1)
    np.testing.assert_allclose(inverse[np.ix_(seen, seen)], floored[np.ix_(seen, seen)], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(np.diag(inverse)[7:9], np.diag(floored)[7:9], rtol=1e-6)
    assert inverse[7, 7] > 1e10 * np.median(np.diag(inverse))


def _whitened_smallest(information, firm, kept):
    whitened = information * np.outer(firm, firm)
    return np.linalg.eigvalsh(whitened[np.ix_(kept, kept)])[0]


def test_soft_parameters_hold_one_of_a_common_mode_and_what_the_data_barely_see():
    """Five offsets seen only through their differences (1 mm each, as fibres that pair with each
    other but never with the reference): their common value is unseen, so one of them is held, as a
    reference fixes a gauge; a sixth seen to 5 cm alone is held; a seventh seen to 2 mm stays."""
    firm = np.full(7, 0.01)
    information = np.zeros((7, 7))
    for i in range(4):  # x_i - x_{i+1} observed with sigma 1 mm
        row = np.zeros(7)
        row[i], row[i + 1] = 1.0, -1.0
        information += np.outer(row, row) / 0.001 ** 2
    information[5, 5], information[6, 6] = 1 / 0.05 ** 2, 1 / 0.002 ** 2
    held = soft_parameters(information, firm)
    assert len(held) == 2 and held[1] == 5 and held[0] in range(5)
    kept = [i for i in range(7) if i not in held]
    assert _whitened_smallest(information, firm, kept) >= 1.0
    sigma = np.sqrt(np.diag(np.linalg.inv(information[np.ix_(kept, kept)])))
    assert np.all(sigma <= 0.01)  # every one left is determined to 1 cm: the chain's ends to about 2 mm


def test_which_of_a_common_mode_is_held_does_not_depend_on_rounding():
    """The chain above, its information perturbed at the rounding level (1e-12 relative, ten draws):
    the common mode's components are then equal but for rounding, and the same offset (the first)
    is held every time."""
    information = np.zeros((5, 5))
    for i in range(4):
        row = np.zeros(5)
        row[i], row[i + 1] = 1.0, -1.0
        information += np.outer(row, row) / 0.001 ** 2
    rng = np.random.default_rng(3)
    helds = set()
    for _ in range(10):
        noise = rng.normal(0.0, 1e-12, (5, 5))
        helds.add(tuple(soft_parameters(information * (1.0 + noise + noise.T), np.full(5, 0.01))))
    assert helds == {(0,)}


def test_soft_parameters_keep_everything_well_determined_and_whiten_by_unit():
    information = np.diag([1 / 0.005 ** 2, 1 / np.radians(0.02) ** 2])  # 5 mm and 0.02 deg
    assert soft_parameters(information, np.array([0.01, np.radians(0.05)])) == []
    assert soft_parameters(information, np.array([0.001, np.radians(0.05)])) == [0]  # 5 mm is soft against 1 mm


@pytest.mark.parametrize("dense_from", [0.0, 1.1])  # factorised dense, sparse
def test_marginals_of_many_keys_made_a_chunk_at_a_time_match_the_dense_inverse(monkeypatch, dense_from):
    """A chain of 40 keys (controls tied to their neighbours) all seen with a calibration key, marginal blocks asked
    key after key in chunks of 7 columns: the bread's and a sandwich's equal the dense H^-1 and H^-1 M H^-1."""
    monkeypatch.setattr(observability, "CHUNK_COLUMNS", 7)
    monkeypatch.setattr(observability, "DENSE_FROM", dense_from)
    rng = np.random.default_rng(4)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    values.insert(0, rng.normal(0, 1, 4))
    graph.add(gtsam.PriorFactorVector(0, np.zeros(4), gtsam.noiseModel.Isotropic.Sigma(4, 1.0)))
    for key in range(1, 41):
        values.insert(key, rng.normal(0, 1, 3))
        graph.add(gtsam.PriorFactorPoint3(key, np.zeros(3), gtsam.noiseModel.Isotropic.Sigma(3, 3.0)))
        if key > 1:
            graph.add(gtsam.BetweenFactorPoint3(key - 1, key, np.ones(3), gtsam.noiseModel.Isotropic.Sigma(3, 0.1)))
    bread = FactorisedMarginals(graph, values)
    H = bread.information.toarray()
    H[:4, 4:] = rng.normal(0, 0.1, (4, 120))  # the calibration key seen with every control
    H[4:, :4] = H[:4, 4:].T
    H[:4, :4] += 20 * np.eye(4)
    bread = FactorisedMarginals.of(sparse.csc_matrix(H), {0: 4, **{key: 3 for key in range(1, 41)}})
    root = sparse.random(124, 124, density=0.05, random_state=5)
    meat = (root @ root.T).toarray()
    H_inv = np.linalg.inv(H)
    whole = H_inv @ meat @ H_inv
    sandwich = bread.sandwich(Meat(sparse.csr_matrix(meat)))
    spans = {0: slice(0, 4), **{key: slice(3 * key + 1, 3 * key + 4) for key in range(1, 41)}}
    for key, span in spans.items():
        np.testing.assert_allclose(bread.marginalCovariance(key), H_inv[span, span], rtol=1e-9, atol=1e-14)
        np.testing.assert_allclose(sandwich.marginalCovariance(key), whole[span, span], rtol=1e-9, atol=1e-14)
    np.testing.assert_allclose(sandwich.jointCovariance(0, 17), whole[spans[0], spans[17]], rtol=1e-9, atol=1e-14)
    np.testing.assert_allclose(bread.jointCovariance(0, 17), H_inv[spans[0], spans[17]], rtol=1e-9, atol=1e-14)
    np.testing.assert_allclose(bread.rows(np.arange(4)), H_inv[:4], rtol=1e-9, atol=1e-14)


def test_key_density_counts_the_entries_a_chain_reaches():
    """Ten Point3 keys in a chain (a prior on the first, a difference between neighbours) and one Vector4 key
    tied to the last: the key pairs joined are the diagonal and the neighbours."""
    from graphcal.calibration.observability import key_density

    graph = gtsam.NonlinearFactorGraph()
    noise3 = gtsam.noiseModel.Isotropic.Sigma(3, 1.0)
    graph.add(gtsam.PriorFactorPoint3(0, np.zeros(3), noise3))
    for k in range(1, 10):
        graph.add(gtsam.BetweenFactorPoint3(k - 1, k, np.zeros(3), noise3))
    graph.add(gtsam.CustomFactor(gtsam.noiseModel.Isotropic.Sigma(1, 1.0), [9, 10], lambda *_: np.zeros(1)))
    widths = {k: 3 for k in range(10)} | {10: 4}
    reached = 10 * 9 + 2 * 9 * 9 + 16 + 2 * 12  # the chain's blocks, the Vector4's own and its pair with key 9
    assert key_density(graph, widths) == pytest.approx(reached / 34 ** 2, rel=1e-12)


def test_held_parameters_have_no_sigma_to_report():
    """Uncertainty.without: NaN exactly at the held intrinsic, extrinsic and control names, the rest untouched."""
    sigmas = observability.Uncertainty(np.full((3, 4), 0.5), np.ones((3, 4)), np.full(6, 0.2), np.ones(6),
                                       np.full((2, 6), 0.1), np.ones((2, 6)))
    held = {"fibre_1.d_azimuth_deg", "fibre_1.h_z_m", "extrinsic.lever_arm_z_m", "control_1.y_m"}
    out = sigmas.without(held)
    assert np.argwhere(np.isnan(out.intrinsics)).tolist() == [[1, 1], [1, 3]]
    assert np.flatnonzero(np.isnan(out.extrinsic)).tolist() == [5]
    assert np.argwhere(np.isnan(out.controls)).tolist() == [[1, 4]]
    assert not np.isnan(sigmas.intrinsics).any()  # a copy: the input keeps its values
    assert np.nansum(out.intrinsics) == 0.5 * 10 and np.nansum(out.controls) == pytest.approx(0.1 * 11)
