"""Block point-to-plane factor: Jacobians vs finite differences, exact compression, robust rows."""

import gtsam
import numpy as np
import pytest
import scipy.linalg

from factors import so3
from factors.point_to_plane import Block, BlockKeys, compress, jacobian_by_key, make_factor, residuals
from factors.world_point import Returns
from graphcal.recording.sensor import sensor_from_catalog

X = gtsam.symbol_shorthand.X
I = gtsam.symbol_shorthand.I
E = gtsam.symbol_shorthand.E
N = 400


def _returns(rng, sensor, fibre):
    fibres = np.full(N, fibre)
    return Returns(range_m=rng.uniform(3, 40, N), azimuth_rad=rng.uniform(0, 2 * np.pi, N),
                   factory=sensor.factory_terms(fibres), R_nav=so3.exp(rng.normal(0, 0.3, (N, 3))),
                   X_nav=rng.normal(0, 20, (N, 3)), alpha=rng.uniform(0, 1, N))


def _keys(layout: str, rng) -> BlockKeys:
    if layout == "shared-control":  # p in interval (0, 1), m in (1, 2): key X(1) is both p_hi and m_lo
        return BlockKeys.of(N, intrinsic_p=I(3), intrinsic_m=I(5), extrinsic=E(0), p_lo=X(0), p_hi=X(1),
                            m_lo=X(1), m_hi=X(2))
    if layout == "distinct-controls":
        return BlockKeys.of(N, intrinsic_p=I(3), intrinsic_m=I(5), extrinsic=E(0), p_lo=X(0), p_hi=X(1),
                            m_lo=X(2), m_hi=X(3))
    # rows of several fibre pairs (the reference fibre 15 among them: no key) and control intervals
    fibre_p, fibre_m = rng.choice([3, 5, 15], N), rng.choice([3, 5, 7, 15], N)
    c_p, c_m = rng.integers(0, 3, N), rng.integers(0, 3, N)
    key_of = np.vectorize(lambda f: -1 if f == 15 else I(int(f)), otypes=[np.int64])
    control = np.vectorize(lambda c: X(int(c)), otypes=[np.int64])
    return BlockKeys.of(N, intrinsic_p=key_of(fibre_p), intrinsic_m=key_of(fibre_m), extrinsic=E(0),
                        p_lo=control(c_p), p_hi=control(c_p + 1), m_lo=control(c_m), m_hi=control(c_m + 1))


def _problem(pose: bool, layout: str = "shared-control", held: bool = False):
    rng = np.random.default_rng(11)
    sensor = sensor_from_catalog("HDL-32E")
    normal = rng.normal(0, 1, (N, 3))
    keys = _keys(layout, rng)
    offsets = (rng.normal(0, 0.01, (N, 3)), rng.normal(0, 0.01, (N, 3))) if held else (None, None)
    block = Block(p=_returns(rng, sensor, 3), m=_returns(rng, sensor, 5),
                  normal=normal / np.linalg.norm(normal, axis=1, keepdims=True),
                  weight=rng.uniform(0.2, 1.0, N), keys=keys, pose_corrections=pose,
                  p_held_l=offsets[0], m_held_l=offsets[1])
    values = gtsam.Values()
    for fibre in (3, 5, 7):
        values.insert(I(fibre), rng.normal(0, 0.02, 4))
    values.insert(E(0), gtsam.Pose3(gtsam.Rot3(so3.exp(rng.normal(0, 1, (1, 3)))[0]), rng.normal(0, 1, 3)))
    for c in range(4):
        if pose:
            values.insert(X(c), gtsam.Pose3(gtsam.Rot3(so3.exp(rng.normal(0, 0.01, (1, 3)))[0]),
                                            rng.normal(0, 0.1, 3)))
        else:
            values.insert(X(c), rng.normal(0, 0.1, 3))
    return block, values


def _perturbed(values, key, delta):
    step = gtsam.VectorValues()
    step.insert(key, delta)
    return values.retract(step)


@pytest.mark.parametrize("pose", [False, True], ids=["translation", "pose"])
@pytest.mark.parametrize("layout", ["shared-control", "distinct-controls", "rows-vary", "held-offsets"])
def test_block_jacobians_match_finite_differences(pose, layout):
    block, values = _problem(pose, "rows-vary" if layout == "held-offsets" else layout, held=layout == "held-offsets")
    _, A = residuals(block, values)
    J = jacobian_by_key(block, A)
    assert set(J) == set(block.keys.unique)
    for key, analytic in J.items():
        dim = analytic.shape[1]
        numeric = np.zeros_like(analytic)
        for k in range(dim):
            d = np.zeros(dim)
            d[k] = 1e-6
            plus, _ = residuals(block, _perturbed(values, key, d), jacobians=False)
            minus, _ = residuals(block, _perturbed(values, key, -d), jacobians=False)
            numeric[:, k] = (plus - minus) / 2e-6
        np.testing.assert_allclose(analytic, numeric, atol=1e-4 * max(1.0, np.abs(numeric).max()))


@pytest.mark.parametrize("pose", [False, True], ids=["translation", "pose"])
@pytest.mark.parametrize("layout", ["shared-control", "rows-vary"])
def test_stacked_factor_linearises_to_the_analytic_jacobians(pose, layout):
    block, values = _problem(pose, layout)
    factor = make_factor(block, compressed=False)
    r, J = residuals(block, values)
    assert factor.error(values) == pytest.approx(0.5 * r @ r, rel=1e-12)
    assert list(factor.keys()) == list(block.keys.unique)
    A, b = factor.linearize(values).jacobian()
    np.testing.assert_allclose(A, J, atol=1e-12)
    np.testing.assert_allclose(b, -r, atol=1e-12)


@pytest.mark.parametrize("pose", [False, True], ids=["translation", "pose"])
@pytest.mark.parametrize("layout", ["shared-control", "rows-vary"])
def test_compressed_factor_keeps_cost_gradient_and_hessian(pose, layout):
    block, values = _problem(pose, layout)
    stacked, small = make_factor(block, compressed=False), make_factor(block, compressed=True)
    assert small.dim() == residuals(block, values)[1].shape[1] + 1 < stacked.dim()
    assert small.error(values) == pytest.approx(stacked.error(values), rel=1e-10)
    A, b = stacked.linearize(values).jacobian()
    A_small, b_small = small.linearize(values).jacobian()
    np.testing.assert_allclose(A_small.T @ A_small, A.T @ A, rtol=1e-9, atol=1e-9 * np.abs(A.T @ A).max())
    np.testing.assert_allclose(A_small.T @ b_small, A.T @ b, rtol=1e-9, atol=1e-9 * np.abs(A.T @ b).max())
    assert b_small @ b_small == pytest.approx(b @ b, rel=1e-10)


@pytest.mark.parametrize("rank", [0, 2, 40, 60])
def test_compress_is_exact_for_rank_deficient_blocks(rank):
    """Blocks whose rows see only some directions of their keys (a column of zeros, columns mixed from fewer
    directions, columns of very different sizes): R^T R = A^T A, R^T z = A^T r, |z| = |r|, as a QR gives."""
    rng = np.random.default_rng(rank)
    A = rng.normal(size=(300, rank)) @ rng.normal(size=(rank, 60)) * np.logspace(-4, 4, 60)
    A[:, 7] = 0.0
    r = rng.normal(size=300)
    z, R = compress(r, A)
    assert R.shape == (61, 60) and z.shape == (61,) and not R[-1].any()
    assert z @ z == pytest.approx(r @ r)
    np.testing.assert_allclose(R.T @ R, A.T @ A, atol=1e-12 * max(np.abs(A.T @ A).max(), 1))
    np.testing.assert_allclose(R.T @ z, A.T @ r, atol=1e-10 * max(np.abs(A.T @ r).max(), 1))
    columns = A / np.where(np.linalg.norm(A, axis=0) > 0, np.linalg.norm(A, axis=0), 1.0)
    basis = scipy.linalg.orth(columns)  # A's column space, by an SVD
    assert basis.shape[1] == min(rank, 59)
    assert np.linalg.norm(z[:-1]) == pytest.approx(np.linalg.norm(basis.T @ r), abs=1e-9)


def test_robust_loss_weights_each_row():
    block, values = _problem(pose=False)
    k = 1.0
    huber = gtsam.noiseModel.mEstimator.Huber.Create(k, gtsam.noiseModel.mEstimator.Base.ReweightScheme.Scalar)
    factor = make_factor(block, compressed=False, robust=huber)
    r, _ = residuals(block, values, jacobians=False)
    per_row = np.where(np.abs(r) <= k, 0.5 * r**2, k * np.abs(r) - 0.5 * k**2)
    assert factor.error(values) == pytest.approx(per_row.sum(), rel=1e-9)
    with pytest.raises(ValueError, match="stacked"):
        make_factor(block, compressed=True, robust=huber)


def test_reference_fibre_and_fixed_slots_have_no_key():
    block, values = _problem(pose=False)
    fixed = Block(p=block.p, m=block.m, normal=block.normal, weight=block.weight,
                  keys=BlockKeys.of(N, intrinsic_m=I(5)), pose_corrections=False)
    factor = make_factor(fixed)
    assert list(factor.keys()) == [I(5)]
    A, _ = factor.linearize(values).jacobian()
    assert A.shape[1] == 4


def test_incidence_sigma_is_the_spread_of_range_noise_along_the_lines_of_sight():
    """incidence_sigma_m against a Monte Carlo of n.(p - m) when p and m move along their lines of sight by
    independent range noise (plus the floor, drawn as its own independent term) and the surface leaves
    the plane at p by an out-of-plane scatter of 3 mm."""
    from factors.point_to_plane import INCIDENCE_FLOOR, incidence_sigma_m

    rng = np.random.default_rng(5)
    unit = lambda v: v / np.linalg.norm(v, axis=-1, keepdims=True)  # noqa: E731
    normal, ray_p, ray_m = (unit(rng.normal(0, 1, (1, 3))) for _ in range(3))
    draws, sigma_m = 200_000, 0.01
    eps_p, eps_m, floor = (rng.normal(0, sigma_m, draws) for _ in range(3))
    out_of_plane = rng.normal(0, 0.003, draws)
    r = (normal @ ray_p.T) * eps_p - (normal @ ray_m.T) * eps_m + INCIDENCE_FLOOR * floor + out_of_plane
    expected = incidence_sigma_m(normal, ray_p, ray_m, sigma_m, np.array([0.003]))[0]
    assert r.std() == pytest.approx(expected, rel=0.01)


@pytest.mark.parametrize("apart", [True, False])
def test_pose_noise_sigma_is_the_spread_of_white_pose_noise(apart):
    """pose_noise_sigma_m against a Monte Carlo of n.(p - m) when every pose sample carries white position
    and attitude noise and each return's pose is interpolated linearly between two samples at a uniform
    random place: p and m in different sample intervals (independent noise), or fired at the same time
    (shared noise, only the attitude's turn of p - m remains)."""
    from factors.point_to_plane import pose_noise_sigma_m

    rng = np.random.default_rng(8)
    normal = np.array([[0.2, -0.3, 0.93]])
    normal /= np.linalg.norm(normal)
    lever_p, lever_m = np.array([[8.0, 3.0, -1.5]]), np.array([[7.5, 3.6, -1.4]])
    draws, sigma_m, sigma_rad = 200_000, 0.005, np.radians(0.01)

    def pose_error(lever):
        a = rng.uniform(0, 1, (draws, 1))
        position = (1 - a) * rng.normal(0, sigma_m, (draws, 3)) + a * rng.normal(0, sigma_m, (draws, 3))
        turn = (1 - a) * rng.normal(0, sigma_rad, (draws, 3)) + a * rng.normal(0, sigma_rad, (draws, 3))
        return position, turn

    position_p, turn_p = pose_error(lever_p)
    position_m, turn_m = pose_error(lever_m) if apart else (position_p, turn_p)
    moved_p = position_p + np.cross(turn_p, lever_p)
    moved_m = position_m + np.cross(turn_m, lever_m)
    r = (moved_p - moved_m) @ normal[0]
    expected = pose_noise_sigma_m(normal, lever_p, lever_m, np.array([0.02 if apart else 0.0]), 0.01, sigma_m,
                                  sigma_rad)[0]
    assert r.std() == pytest.approx(expected, rel=0.02)
