"""Candidate effects (factors/effects.py): what each channel does to a return, and the block
factor's Jacobians with respect to the effect keys against finite differences."""

import gtsam
import numpy as np
import pytest

from factors import so3
from factors.channels import Channels, Context, Motion, perturbed
from factors.discrepancy import Discrepancy
from factors.effects import CANDIDATES, candidate
from factors.point_to_plane import (
    Block,
    BlockKeys,
    EffectTerms,
    jacobian_by_key,
    residuals,
)
from factors.world_point import Returns
from graphcal.recording.sensor import sensor_from_catalog

X = gtsam.symbol_shorthand.X
I = gtsam.symbol_shorthand.I
E = gtsam.symbol_shorthand.E
K = gtsam.symbol_shorthand.K
N = 300


def _returns(rng, sensor):
    fibre = rng.integers(0, sensor.n_fibres, N)
    returns = Returns(range_m=rng.uniform(3, 40, N), azimuth_rad=rng.uniform(0, 2 * np.pi, N),
                      factory=sensor.factory_terms(fibre), R_nav=so3.exp(rng.normal(0, 0.3, (N, 3))),
                      X_nav=rng.normal(0, 20, (N, 3)), alpha=rng.uniform(0, 1, N))
    context = Context(returns.range_m, returns.azimuth_rad, fibre, sensor.n_fibres, rng.uniform(0, 0.1, N),
                      rng.uniform(0, 6, N), rng.uniform(0.05, 1, N), returns.X_nav, intensity=rng.uniform(0, 255, N),
                      speed_m_s=rng.uniform(0, 15, N), yaw_rate_rad_s=rng.normal(0, 0.3, N))
    motion = Motion(rng.normal(0, 8, (N, 3)), rng.normal(0, 0.5, (N, 3)))
    return returns, context, motion


def test_time_channel_moves_the_pose_along_a_constant_rate_motion():
    rng = np.random.default_rng(1)
    returns, _, motion = _returns(rng, sensor_from_catalog("HDL-32E"))
    dt = rng.normal(0, 0.01, N)
    zero = np.zeros(N)
    channels = Channels(range=zero, azimuth=zero, elevation=zero, horizontal=zero, time=dt, heading=zero,
                        body=np.zeros((N, 3)), position=np.zeros((N, 3)))
    moved = perturbed(returns, motion, channels)
    # the pose at t + dt of a motion with constant velocity and world-axes angular rate
    np.testing.assert_allclose(moved.R_nav, so3.exp(motion.omega * dt[:, None]) @ returns.R_nav, atol=1e-12)
    np.testing.assert_allclose(moved.X_nav, returns.X_nav + motion.velocity * dt[:, None], atol=1e-12)


def _block(name, pose, m_moves, seed=3):
    rng = np.random.default_rng(seed)
    sensor = sensor_from_catalog("HDL-64E")  # non-zero factory terms: the general form
    p, context_p, motion_p = _returns(rng, sensor)
    m, context_m, motion_m = _returns(rng, sensor)
    normal = rng.normal(0, 1, (N, 3))
    model = candidate(name)
    keys = BlockKeys.of(N, intrinsic_p=I(3), intrinsic_m=I(5), extrinsic=E(0), p_lo=X(0), p_hi=X(1), m_lo=X(1),
                        m_hi=X(2))
    terms = EffectTerms((K(0),), (model.basis(context_p),), motion_p,
                        (model.basis(context_m),) if m_moves else None, motion_m if m_moves else None)
    block = Block(p=p, m=m, normal=normal / np.linalg.norm(normal, axis=1, keepdims=True),
                  weight=rng.uniform(0.2, 1.0, N), keys=keys, pose_corrections=pose, effects=terms)
    values = gtsam.Values()
    for fibre in (3, 5):
        values.insert(I(fibre), rng.normal(0, 0.02, 4))
    values.insert(E(0), gtsam.Pose3(gtsam.Rot3(so3.exp(rng.normal(0, 1, (1, 3)))[0]), rng.normal(0, 1, 3)))
    for c in range(3):
        values.insert(X(c), gtsam.Pose3(gtsam.Rot3(so3.exp(rng.normal(0, 0.01, (1, 3)))[0]), rng.normal(0, 0.1, 3))
                      if pose else rng.normal(0, 0.1, 3))
    dim = model.dim(sensor.n_fibres)
    values.insert(K(0), rng.normal(0, 1e-3, dim))  # Jacobians checked away from zero too
    return block, values


# generic discrepancies: every channel, a B-spline, a Fourier and a per-fibre basis, regressors of every source
DISCREPANCIES = [Discrepancy.uniform(*spec).name for spec in (
    ("range", "intensity", 6, 10.0, 240.0), ("azimuth", "azimuth", 4, 0, 360), ("elevation", "range", 5, 4.0, 38.0),
    ("time", "fibre", 63, 0, 63), ("time", "yaw_rate", 4, -20.0, 20.0), ("range", "speed", 4, 1.0, 14.0))]


@pytest.mark.parametrize("name", sorted(CANDIDATES) + DISCREPANCIES)
@pytest.mark.parametrize("pose", [False, True], ids=["translation", "pose"])
def test_effect_key_jacobians_match_finite_differences(name, pose):
    block, values = _block(name, pose, m_moves=True)
    _, A = residuals(block, values)
    J = jacobian_by_key(block, A)
    assert set(J) == set(block.keys.unique) | {K(0)}
    for key, analytic in J.items():
        numeric = np.zeros_like(analytic)
        for k in range(analytic.shape[1]):
            step = gtsam.VectorValues()
            d = np.zeros(analytic.shape[1])
            d[k] = 1e-6
            step.insert(key, d)
            plus, _ = residuals(block, values.retract(step), jacobians=False)
            minus_values = gtsam.VectorValues()
            minus_values.insert(key, -d)
            minus, _ = residuals(block, values.retract(minus_values), jacobians=False)
            numeric[:, k] = (plus - minus) / 2e-6
        scale = max(np.abs(numeric).max(), 1.0)
        np.testing.assert_allclose(analytic, numeric, atol=2e-5 * scale, err_msg=f"{name}: key {key}")


def test_fixed_map_points_are_not_moved_by_the_effects():
    block, values = _block("time_offset", pose=False, m_moves=False)
    _, A = residuals(block, values)
    assert np.abs(A[:, block.offsets[K(0)]]).max() > 0
    moved, _ = _block("time_offset", pose=False, m_moves=True)
    _, A_moved = residuals(moved, values)
    assert not np.allclose(A[:, block.offsets[K(0)]], A_moved[:, moved.offsets[K(0)]])
