"""The outer loop: associate -> build one GTSAM graph -> Levenberg-Marquardt -> update (ICP-like).

Energy of eq. 4.4/5.2: J = sum w d^2 / sum w, reported in cm^2, with d the point-to-plane
distance; the graph's cost is (W / sigma0^2) J + priors, so lambda_rigid's prior (eq. 5.3) has
sigma = sigma0 / sqrt(lambda_rigid W) on each control correction.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import gtsam
import numpy as np

from factors.point_to_plane import Block, BlockKeys, FixedValues, make_factor
from graphcal.association import (
    Correspondences,
    associate,
    local_features,
    neighbour_fibres,
)
from graphcal.calibration.config import ESTIMATES, CalibrationConfig
from graphcal.calibration.problem import Estimate, ReturnData, world_at
from graphcal.progress import progress

I = gtsam.symbol_shorthand.I  # noqa: E741  per-fibre intrinsic offsets, Vector4
E = gtsam.symbol_shorthand.E  # extrinsic T_body_lidar, Pose3
X = gtsam.symbol_shorthand.X  # trajectory correction at a control time, Point3 or Pose3

# weak priors that keep directions the data cannot see well-posed (m, rad, rad, m)
INTRINSIC_PRIOR_SIGMA = np.array([1.0, 0.3, 0.3, 1.0])
CANDIDATES_PER_FIBRE = 20_000


@dataclass
class History:
    """Per outer iteration: J [cm^2] before/after the solve, weight sum, pairs, gate [m], step."""

    rows: list = field(default_factory=list)

    def add(self, **row) -> None:
        self.rows.append(row)


def energy_cm2(p_m: np.ndarray, m_m: np.ndarray, pairs: Correspondences) -> tuple[float, float]:
    """(J [cm^2], weight sum) of eq. 4.4 for the paired world points p, m (K,3) [m], with the
    correspondences' fixed normals and weights."""
    d = np.einsum("ni,ni->n", pairs.normal, p_m - m_m)
    weight_sum = float(pairs.weight.sum())
    return float((pairs.weight * d * d).sum() / weight_sum * 1e4), weight_sum


def build_graph(data: ReturnData, estimate: Estimate, pairs: Correspondences, config: CalibrationConfig,
                estimates: tuple[bool, bool, bool], nominal_extrinsic: gtsam.Pose3):
    """One graph: a block factor per (fibre i, fibre j, control of p, control of m), plus priors."""
    est_int, est_ext, est_traj = estimates
    pose = config.pose_corrections
    ref = data.sensor.reference_fibre
    fi, fj = data.fibre[pairs.index_p], data.fibre[pairs.index_m]
    cp = data.control[pairs.index_p] if est_traj else np.zeros(len(pairs), int)
    cm = data.control[pairs.index_m] if est_traj else np.zeros(len(pairs), int)
    group = np.stack([fi, fj, cp, cm], axis=1)
    unique, inverse = np.unique(group, axis=0, return_inverse=True)
    order = np.argsort(inverse.ravel(), kind="stable")
    bounds = np.searchsorted(inverse.ravel()[order], np.arange(len(unique) + 1))
    robust = None
    if config.robust != "none":
        scheme = gtsam.noiseModel.mEstimator.Base.ReweightScheme.Scalar
        create = {"huber": gtsam.noiseModel.mEstimator.Huber, "cauchy": gtsam.noiseModel.mEstimator.Cauchy}
        robust = create[config.robust].Create(config.robust_k, scheme)

    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for (i, j, c_p, c_m), start, stop in zip(unique, bounds[:-1], bounds[1:]):
        rows = order[start:stop]
        keys = BlockKeys(intrinsic_p=I(i) if est_int and i != ref else None,
                         intrinsic_m=I(j) if est_int and j != ref else None,
                         extrinsic=E(0) if est_ext else None,
                         p_lo=X(c_p) if est_traj else None, p_hi=X(c_p + 1) if est_traj else None,
                         m_lo=X(c_m) if est_traj else None, m_hi=X(c_m + 1) if est_traj else None)
        if not keys.unique():
            continue
        block = Block(p=data.returns(pairs.index_p[rows]), m=data.returns(pairs.index_m[rows]),
                      normal=pairs.normal[rows], weight=pairs.weight[rows], keys=keys, pose_corrections=pose,
                      fixed=FixedValues(estimate.offsets[i], estimate.offsets[j], estimate.extrinsic),
                      sigma0_m=config.sigma0_m)
        graph.add(make_factor(block, compressed=robust is None, robust=robust))

    if est_int:
        for fibre in range(data.sensor.n_fibres):
            if fibre != ref:
                values.insert(I(fibre), estimate.offsets[fibre])
                graph.add(gtsam.PriorFactorVector(I(fibre), np.zeros(4),
                                                  gtsam.noiseModel.Diagonal.Sigmas(INTRINSIC_PRIOR_SIGMA)))
    if est_ext:
        values.insert(E(0), estimate.extrinsic)
        sigmas = np.r_[np.full(3, np.radians(config.extrinsic_sigma_boresight_deg)),
                       np.full(3, config.extrinsic_sigma_lever_arm_m)]
        graph.add(gtsam.PriorFactorPose3(E(0), nominal_extrinsic, gtsam.noiseModel.Diagonal.Sigmas(sigmas)))
    if est_traj:
        _add_trajectory(graph, values, estimate, config, float(pairs.weight.sum()))
    return graph, values


def _add_trajectory(graph, values, estimate: Estimate, config: CalibrationConfig, weight_sum: float) -> None:
    """Control corrections and E_def (eq. 5.3) or Monnier's successive differences."""
    sigma = config.sigma0_m / np.sqrt(config.lambda_rigid * weight_sum)
    pose = config.pose_corrections
    noise = gtsam.noiseModel.Isotropic.Sigma(6 if pose else 3, sigma)  # rotations: rad x 1 m
    for c, correction in enumerate(estimate.corrections):
        values.insert(X(c), correction if pose else correction.translation())
        if config.deformation == "prior" or c == 0:
            graph.add(gtsam.PriorFactorPose3(X(c), gtsam.Pose3(), noise) if pose
                      else gtsam.PriorFactorPoint3(X(c), np.zeros(3), noise))
        if config.deformation == "monnier" and c > 0:
            graph.add(gtsam.BetweenFactorPose3(X(c - 1), X(c), gtsam.Pose3(), noise) if pose
                      else gtsam.BetweenFactorPoint3(X(c - 1), X(c), np.zeros(3), noise))


def read_back(values: gtsam.Values, estimate: Estimate, estimates, data: ReturnData, pose: bool) -> Estimate:
    """The estimate held in solved values."""
    est_int, est_ext, est_traj = estimates
    offsets = estimate.offsets.copy()
    if est_int:
        for fibre in range(data.sensor.n_fibres):
            if fibre != data.sensor.reference_fibre:
                offsets[fibre] = values.atVector(I(fibre))
    extrinsic = values.atPose3(E(0)) if est_ext else estimate.extrinsic
    corrections = estimate.corrections
    if est_traj:
        corrections = tuple(values.atPose3(X(c)) if pose else gtsam.Pose3(gtsam.Rot3(), values.atPoint3(X(c)))
                            for c in range(len(corrections)))
    return Estimate(offsets, extrinsic, corrections)


def step_size(a: Estimate, b: Estimate) -> float:
    """max |dX| over every parameter: m for lengths, rad (x 1 m) for angles."""
    steps = [np.abs(a.offsets - b.offsets).max(), np.abs(a.extrinsic.localCoordinates(b.extrinsic)).max()]
    steps += [np.abs(x.localCoordinates(y)).max() for x, y in zip(a.corrections, b.corrections)]
    return float(max(steps))


def solve_stage(data: ReturnData, estimate: Estimate, config: CalibrationConfig, mode: str,
                nominal_extrinsic: gtsam.Pose3, history: History, quiet: bool = False):
    """Outer iterations of one single-stage mode until max |dX| < tolerance or n_max.
    Returns (estimate, last graph, last values)."""
    estimates = ESTIMATES[mode]
    pose = config.pose_corrections
    rng = np.random.default_rng(config.seed)
    neighbours = neighbour_fibres(data.sensor.elevation_deg, config.neighbours)
    candidates = _candidates(data, rng)
    features, gate, graph, values = None, config.gate_start_m, None, None
    for iteration in progress(range(config.max_outer_iterations), f"calibrating ({mode})",
                              total=config.max_outer_iterations, quiet=quiet):
        points = world_at(data, estimate, pose)
        if iteration % config.refresh_every == 0:
            features = local_features(points, config.feature_radius_m, config.feature_neighbours, candidates)
        pairs = associate(points, data.fibre, features, neighbours, gate, config.min_planarity,
                          config.max_pairs_per_fibre_pair, rng, candidates)
        before, weight_sum = energy_cm2(points[pairs.index_p], points[pairs.index_m], pairs)
        graph, values = build_graph(data, estimate, pairs, config, estimates, nominal_extrinsic)
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(config.lm_iterations)
        solved = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
        updated = read_back(solved, estimate, estimates, data, pose)
        step = step_size(estimate, updated)
        after, _ = energy_cm2(world_at(data, updated, pose, pairs.index_p),
                              world_at(data, updated, pose, pairs.index_m), pairs)
        history.add(mode=mode, iteration=len(history.rows), energy_cm2=before, energy_after_cm2=after,
                    weight_sum=weight_sum, pairs=len(pairs), gate_m=gate, max_step=step,
                    refreshed=iteration % config.refresh_every == 0)
        estimate, values = updated, solved
        gate = min(gate * config.gate_growth, config.gate_max_m)
        if step < config.tolerance_m:
            break
    return estimate, graph, values


def _candidates(data: ReturnData, rng: np.random.Generator) -> np.ndarray:
    """Up to CANDIDATES_PER_FIBRE random returns of each fibre: the p's of eq. 4.4."""
    rows = []
    for fibre in np.unique(data.fibre):
        of_fibre = np.flatnonzero(data.fibre == fibre)
        if len(of_fibre) > CANDIDATES_PER_FIBRE:
            of_fibre = np.sort(rng.choice(of_fibre, CANDIDATES_PER_FIBRE, replace=False))
        rows.append(of_fibre)
    return np.sort(np.concatenate(rows))
