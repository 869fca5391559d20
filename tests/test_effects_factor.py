"""Candidate effects (factors/effects.py): what each channel does to a return, and the block
factor's Jacobians with respect to the effect keys against finite differences."""

from types import SimpleNamespace

import gtsam
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

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
from graphcal.diagnosis.context import ReturnContext, ins_motion
from graphcal.recording.poses import PoseTrack
from graphcal.recording.sensor import sensor_from_catalog

X = gtsam.symbol_shorthand.X
I = gtsam.symbol_shorthand.I
E = gtsam.symbol_shorthand.E
K = gtsam.symbol_shorthand.K
N = 300


def _returns(rng, sensor, shifted=False):
    fibre = rng.integers(0, sensor.n_fibres, N)
    returns = Returns(range_m=rng.uniform(3, 40, N), azimuth_rad=rng.uniform(0, 2 * np.pi, N),
                      factory=sensor.factory_terms(fibre), R_nav=so3.exp(rng.normal(0, 0.3, (N, 3))),
                      X_nav=rng.normal(0, 20, (N, 3)), alpha=rng.uniform(0, 1, N))
    context = Context(returns.range_m, returns.azimuth_rad, fibre, sensor.n_fibres, rng.uniform(0, 0.1, N),
                      rng.uniform(0, 6, N), rng.uniform(0.05, 1, N), returns.X_nav, intensity=rng.uniform(0, 255, N),
                      speed_m_s=rng.uniform(0, 15, N), yaw_rate_rad_s=rng.normal(0, 0.3, N))
    motion = Motion(rng.normal(0, 8, (N, 3)), rng.normal(0, 0.5, (N, 3)))
    if shifted:  # taken about a shift of up to a revolution, with the pose's step over it
        motion = Motion(motion.velocity, motion.omega, rng.uniform(0, 0.1, N), rng.normal(0, 0.5, (N, 3)),
                        so3.exp(rng.normal(0, 0.05, (N, 3))))
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


def test_time_channel_at_the_shift_it_is_taken_about_is_the_step_itself():
    rng = np.random.default_rng(2)
    returns, _, motion = _returns(rng, sensor_from_catalog("HDL-32E"), shifted=True)
    zero = np.zeros(N)
    channels = Channels(range=zero, azimuth=zero, elevation=zero, horizontal=zero, time=motion.about_s, heading=zero,
                        body=np.zeros((N, 3)), position=np.zeros((N, 3)))
    moved = perturbed(returns, motion, channels)
    np.testing.assert_allclose(moved.R_nav, motion.step_rotation @ returns.R_nav, atol=1e-12)
    np.testing.assert_allclose(moved.X_nav, returns.X_nav + motion.step_position_m, atol=1e-12)


def _block(name, pose, m_moves, seed=3, shifted=False):
    rng = np.random.default_rng(seed)
    sensor = sensor_from_catalog("HDL-64E")  # non-zero factory terms: the general form
    p, context_p, motion_p = _returns(rng, sensor, shifted)
    m, context_m, motion_m = _returns(rng, sensor, shifted)
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
    _check_jacobians(*_block(name, pose, m_moves=True))


@pytest.mark.parametrize("name", ["time_offset", "intra_sweep_motion", "heading_drift", DISCREPANCIES[3]])
def test_effect_key_jacobians_about_a_shifted_time_match_finite_differences(name):
    _check_jacobians(*_block(name, pose=True, m_moves=True, shifted=True))


def _check_jacobians(block, values):
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
        np.testing.assert_allclose(analytic, numeric, atol=2e-5 * scale, err_msg=f"key {key}")


def test_fixed_map_points_are_not_moved_by_the_effects():
    block, values = _block("time_offset", pose=False, m_moves=False)
    _, A = residuals(block, values)
    assert np.abs(A[:, block.offsets[K(0)]]).max() > 0
    moved, _ = _block("time_offset", pose=False, m_moves=True)
    _, A_moved = residuals(moved, values)
    assert not np.allclose(A[:, block.offsets[K(0)]], A_moved[:, moved.offsets[K(0)]])


def test_a_shift_of_a_revolution_follows_the_drive_s_own_path():
    """A return's time shifted by up to a revolution (0.1 s) in a turn that tightens and a climb that steepens:
    the motion taken about the shift (ReturnContext.motion) reaches the pose the track has at the shifted time,
    where the motion at the stamp held over the shift misses it by millimetres."""
    rng = np.random.default_rng(4)
    time = np.arange(0.0, 4.0, 0.005)
    yaw = 0.15 * time ** 2  # yaw rate 0 -> 1.2 rad/s
    track = PoseTrack(time, np.stack([10 * np.sin(yaw), 10 * (1 - np.cos(yaw)), 0.1 * time ** 2], axis=1),
                      Rotation.from_euler("zx", np.stack([yaw, 0.05 * np.sin(3 * time)], axis=1)))
    t = rng.uniform(0.5, 3.5, N)
    shift = rng.uniform(0.0, 0.1, N)
    velocity, omega = ins_motion(track, t)
    context = ReturnContext(SimpleNamespace(time_s=t), track, *(None,) * 4, velocity, omega)
    rows = np.arange(N)
    position, rotation = track.interpolate(t)
    shifted_position, shifted_rotation = track.interpolate(t + shift)
    for motion, exact in ((context.motion(rows, shift), True), (context.motion(rows), False)):
        position_error = np.linalg.norm(position + motion.step(shift) - shifted_position, axis=1)
        turn = motion.turn(shift) @ rotation.as_matrix()
        angle_error = (Rotation.from_matrix(turn) * shifted_rotation.inv()).magnitude()
        if exact:
            assert position_error.max() < 1e-9 and angle_error.max() < 1e-9
        else:
            assert position_error.max() > 1e-3 and angle_error.max() > 1e-3
