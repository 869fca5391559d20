"""Jacobians of the world point of a return against finite differences through GTSAM's retract."""

import gtsam
import numpy as np
import pytest

from factors import so3
from factors.world_point import (
    Corrections,
    Returns,
    normals_to_lidar,
    on_stand_ins,
    world_normals,
    world_points,
)
from graphcal.recording.sensor import sensor_from_catalog

N = 300


def _rotation(rng, scale):
    return so3.exp(rng.normal(0, scale, (1, 3)))[0]


@pytest.fixture()
def problem():
    rng = np.random.default_rng(7)
    sensor = sensor_from_catalog("HDL-64E")  # factory terms non-zero: the general form
    fibre = rng.integers(0, sensor.n_fibres, N)
    returns = Returns(range_m=rng.uniform(2, 60, N), azimuth_rad=rng.uniform(0, 2 * np.pi, N),
                      factory=sensor.factory_terms(fibre),
                      R_nav=so3.exp(rng.normal(0, 0.5, (N, 3))), X_nav=rng.normal(0, 50, (N, 3)),
                      alpha=rng.uniform(0, 1, N))
    offsets = np.column_stack([rng.normal(0, 0.05, N), rng.normal(0, 0.02, N), rng.normal(0, 0.02, N),
                               rng.normal(0, 0.05, N)])
    E = gtsam.Pose3(gtsam.Rot3(_rotation(rng, 1.0)), rng.normal(0, 1, 3))
    controls = [gtsam.Pose3(gtsam.Rot3(_rotation(rng, 0.01)), rng.normal(0, 0.1, 3)) for _ in range(2)]
    return returns, offsets, E, controls


def _corrections(controls, pose, n=N):
    lo, hi = controls
    tile = lambda a: np.broadcast_to(a, (n,) + np.shape(a)).copy()
    return Corrections(tile(lo.translation()), tile(hi.translation()),
                       tile(lo.rotation().matrix()) if pose else None,
                       tile(hi.rotation().matrix()) if pose else None)


def _evaluate(returns, offsets, E, controls, pose):
    p, J = world_points(returns, offsets, E.rotation().matrix(), E.translation(), _corrections(controls, pose))
    return p, J


def _numeric(f, x0_dim, step):
    columns = []
    for k in range(x0_dim):
        d = np.zeros(x0_dim)
        d[k] = step
        columns.append((f(d) - f(-d)) / (2 * step))
    return np.stack(columns, axis=2)


@pytest.mark.parametrize("pose", [False, True], ids=["translation", "pose"])
def test_jacobians_match_finite_differences(problem, pose):
    returns, offsets, E, controls = problem
    _, J = _evaluate(returns, offsets, E, controls, pose)

    numeric = _numeric(lambda d: _evaluate(returns, offsets + d, E, controls, pose)[0], 4, 1e-6)
    np.testing.assert_allclose(J.intrinsic, numeric, atol=1e-6)

    numeric = _numeric(lambda d: _evaluate(returns, offsets, E.retract(d), controls, pose)[0], 6, 1e-6)
    np.testing.assert_allclose(J.extrinsic, numeric, atol=1e-6)

    for index, analytic in ((0, J.control_lo), (1, J.control_hi)):
        def moved(d, index=index):
            changed = list(controls)
            if pose:
                changed[index] = controls[index].retract(d)
            else:  # a Point3 key: additive; rotations stay unused
                changed[index] = gtsam.Pose3(controls[index].rotation(), controls[index].translation() + d)
            return _evaluate(returns, offsets, E, changed, pose)[0]
        numeric = _numeric(moved, 6 if pose else 3, 1e-6)
        np.testing.assert_allclose(analytic, numeric, atol=1e-6)


@pytest.mark.parametrize("pose", [False, True], ids=["translation", "pose"])
def test_normal_jacobians_match_finite_differences_and_invert(problem, pose):
    returns, _, E, controls = problem
    normal = np.random.default_rng(3).normal(size=(N, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)

    def turned(E, controls):
        return world_normals(returns, E.rotation().matrix(), _corrections(controls, pose), normal)

    n_w, J = turned(E, controls)
    np.testing.assert_allclose(np.linalg.norm(n_w, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(normals_to_lidar(returns, E.rotation().matrix(), _corrections(controls, pose), n_w),
                               normal, atol=1e-12)
    numeric = _numeric(lambda d: turned(E.retract(d), controls)[0], 6, 1e-6)
    np.testing.assert_allclose(J.extrinsic, numeric, atol=1e-6)
    for index, analytic in ((0, J.control_lo), (1, J.control_hi)):
        def moved(d, index=index):
            changed = list(controls)
            changed[index] = (controls[index].retract(d) if pose else
                              gtsam.Pose3(controls[index].rotation(), controls[index].translation() + d))
            return turned(E, changed)[0]
        np.testing.assert_allclose(analytic, _numeric(moved, 6 if pose else 3, 1e-6), atol=1e-6)


def test_a_rigid_turn_of_the_cloud_turns_its_normals():
    """Straight drive along x, body x forward: turning the extrinsic about body x turns every
    point and normal rigidly about the driving line (up to a constant shift), so n . (p - m)
    is unchanged: the roll the data cannot see stays unseen."""
    rng = np.random.default_rng(5)
    sensor = sensor_from_catalog("HDL-32E")
    fibre = rng.integers(0, sensor.n_fibres, N)
    X_nav = np.column_stack([rng.uniform(0, 50, N), np.zeros(N), np.zeros(N)])
    returns = Returns(rng.uniform(2, 40, N), rng.uniform(0, 2 * np.pi, N), sensor.factory_terms(fibre),
                      np.broadcast_to(np.eye(3), (N, 3, 3)), X_nav, rng.uniform(0, 1, N))
    m_rows = rng.permutation(N)
    zero = _corrections([gtsam.Pose3(), gtsam.Pose3()], pose=False)
    E = gtsam.Pose3(gtsam.Rot3.Ypr(np.pi / 2, 0.0, 0.3), np.array([0.8, 0.0, 1.9]))
    normal = rng.normal(size=(N, 3))

    def distances(E):
        p, _ = world_points(returns, np.zeros((N, 4)), E.rotation().matrix(), E.translation(), zero, jacobians=False)
        n, _ = world_normals(returns, E.rotation().matrix(), zero, normal, jacobians=False)
        return np.einsum("ni,ni->n", n, p - p[m_rows])

    rolled = gtsam.Pose3(gtsam.Rot3.Roll(0.01) * E.rotation(), E.translation())  # about body x
    np.testing.assert_allclose(distances(rolled), distances(E), atol=1e-9)


def test_translation_corrections_interpolate_linearly(problem):
    """eq. 5.4: the correction at a return is (1 - alpha) dX_lo + alpha dX_hi."""
    returns, offsets, E, controls = problem
    zero = [gtsam.Pose3(), gtsam.Pose3()]
    base, _ = _evaluate(returns, offsets, E, zero, pose=False)
    moved, _ = _evaluate(returns, offsets, E, controls, pose=False)
    a = returns.alpha[:, None]
    expected = (1 - a) * controls[0].translation() + a * controls[1].translation()
    np.testing.assert_allclose(moved - base, expected, atol=1e-12)


def test_pose_correction_turns_about_the_vehicle(problem):
    """A pure yaw correction at both controls rotates each point about its own X_nav."""
    returns, offsets, E, _ = problem
    yaw = gtsam.Pose3(gtsam.Rot3.Yaw(0.01), np.zeros(3))
    base, _ = _evaluate(returns, offsets, E, [gtsam.Pose3(), gtsam.Pose3()], pose=True)
    turned, _ = _evaluate(returns, offsets, E, [yaw, yaw], pose=True)
    expected = (base - returns.X_nav) @ gtsam.Rot3.Yaw(0.01).matrix().T + returns.X_nav
    np.testing.assert_allclose(turned, expected, atol=1e-9)


def test_right_jacobians_are_inverse_and_match_the_exponential():
    rng = np.random.default_rng(1)
    w = np.vstack([rng.normal(0, 0.6, (20, 3)), rng.normal(0, 1e-8, (3, 3))])  # |w| < pi: Log is unique
    np.testing.assert_allclose(so3.right_jacobian(w) @ so3.right_jacobian_inverse(w),
                               np.broadcast_to(np.eye(3), (len(w), 3, 3)), atol=1e-9)
    d = 1e-7 * rng.normal(0, 1, (len(w), 3))
    lhs = so3.exp(w + d)
    rhs = so3.exp(w) @ so3.exp(np.einsum("nij,nj->ni", so3.right_jacobian(w), d))
    np.testing.assert_allclose(lhs, rhs, atol=1e-13)
    np.testing.assert_allclose(so3.log(so3.exp(w[:20])), w[:20], atol=1e-12)


def test_returns_on_stand_ins_are_the_measured_points_with_offsets_held():
    """on_stand_ins: the returns with their ranges' stand-ins plus the held sensor-frame offsets are the
    measured world points (at the estimate), and without the offsets they are the stand-ins; the
    stand-in of a return's range does not move with its own range, it moves with its neighbours'
    (independent check: change one range, recompute)."""
    import dataclasses

    import graphcal
    from graphcal.calibration.returns import corrections_at, initial_estimate, prepare, sight_at, world_at
    from graphcal.simulation.script import load_scenario_builder

    recording = graphcal.simulate(load_scenario_builder("sim2_street")(size=0.1, seed=2, range_noise_m=0.01),
                                  quiet=True)
    data = prepare(recording, 1.0)
    estimate = initial_estimate(recording, data)
    estimate = dataclasses.replace(estimate, offsets=np.random.default_rng(0).normal(0, 0.01, estimate.offsets.shape))
    points = world_at(data, estimate, pose=False)
    sight = sight_at(data, estimate)
    rows = np.arange(0, len(points), 97)
    offsets = estimate.offsets[data.fibre[rows]]
    returns, held = on_stand_ins(data.returns(rows), offsets, sight.shift_m[rows])
    np.testing.assert_allclose(returns.range_m, data.range_m[rows] + sight.shift_m[rows])
    R_E, t_E = estimate.extrinsic.rotation().matrix(), estimate.extrinsic.translation()
    corrections = corrections_at(estimate, data.control[rows], False)
    with_held, _ = world_points(returns, offsets, R_E, t_E, corrections, jacobians=False, held_lidar=held)
    np.testing.assert_allclose(with_held, points[rows], atol=1e-9)
    at_stand_ins, _ = world_points(returns, offsets, R_E, t_E, corrections, jacobians=False)
    np.testing.assert_allclose(at_stand_ins, sight.stand_ins(points)[rows], atol=1e-6)
    assert np.mean(sight.shift_m != 0) > 0.5  # most returns have firing neighbours near enough
    row = int(np.flatnonzero(sight.shift_m != 0)[100])
    bumped = dataclasses.replace(data, range_m=data.range_m + 0.05 * (np.arange(len(points)) == row))
    again = sight_at(bumped, estimate)
    assert data.range_m[row] + sight.shift_m[row] == pytest.approx(bumped.range_m[row] + again.shift_m[row], abs=1e-9)
    neighbour = row + int(np.flatnonzero(data.fibre[row + 1:] == data.fibre[row])[0]) + 1
    assert again.shift_m[neighbour] != pytest.approx(sight.shift_m[neighbour], abs=1e-4)
