"""The outer loop: associate -> build one GTSAM graph -> Levenberg-Marquardt -> update (ICP-like).

Energy of eq. 4.4/5.2: J = sum w d^2 / sum w, reported in cm^2, with d the point-to-plane
distance; the graph's cost is (W / sigma0^2) (J + lambda_rigid E_def) + priors, eq. 5.4 with J
normalised by the weight sum W, so E_def's prior has sigma = sigma0 / sqrt(lambda_rigid W) on each
control: the balance of data and rigidity does not depend on how many pairs are drawn.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field, replace

import gtsam
import numpy as np
from scipy.spatial.transform import Rotation

from factors.point_to_plane import (
    NO_KEY,
    Block,
    BlockKeys,
    FixedValues,
    incidence_sigma_m,
    make_factor,
    pose_noise_sigma_m,
)
from factors.world_point import normals_to_lidar, on_stand_ins
from graphcal.calibration.association import (
    Correspondences,
    Features,
    Sight,
    associate,
    local_features,
    neighbour_fibres,
)
from graphcal.calibration.config import CalibrationConfig
from graphcal.calibration.observability import (
    CONTROL_NAMES,
    EXTRINSIC_NAMES,
    INTRINSIC_NAMES,
    tangent_to_axes,
)
from graphcal.calibration.problem import Estimate, ReturnData, corrections_at, rays_at, sight_at, world_at
from graphcal.common.progress import progress

I = gtsam.symbol_shorthand.I
E = gtsam.symbol_shorthand.E  # extrinsic T_body_lidar, Pose3
X = gtsam.symbol_shorthand.X  # trajectory correction at a control time, Point3 or Pose3

CANDIDATES_PER_PAIR = 5  # candidate p's of a fibre per pair drawn for each of its fibre pairs
MAX_BLOCK_ROWS = 20_000
HELD_SIGMA = 1e-7  # prior sigma (m or rad) that holds an unobservable parameter at its nominal value


@dataclass
class History:
    """Per outer iteration: J [cm^2] before/after the solve, weight sum, pairs, gate [m], step, and on the
    last of a stage's phase why it stopped (stop: converged, coarse done, or cap: n_max reached)."""

    rows: list = field(default_factory=list)

    def add(self, **row) -> None:
        self.rows.append(row)


@dataclass(frozen=True)
class Priors:
    """Prior 1-sigmas about the nominal values, SI (m, rad): intrinsics (n_fibres, 4); extrinsic
    (6,) rotation then lever arm, both in body axes; control_held (C, 3 or 6) marks control
    components held at zero (their other prior is E_def, set from the weight sum)."""

    intrinsic: np.ndarray
    extrinsic: np.ndarray
    control_held: np.ndarray

    @classmethod
    def of(cls, config: CalibrationConfig, n_fibres: int, n_controls: int) -> Priors:
        one = np.r_[config.intrinsic_sigma_range_m, np.radians(config.intrinsic_sigma_angle_deg),
                    np.radians(config.intrinsic_sigma_angle_deg), config.intrinsic_sigma_range_m]
        extrinsic = np.r_[np.full(3, np.radians(config.extrinsic_sigma_boresight_deg)),
                          np.full(3, config.extrinsic_sigma_lever_arm_m)]
        return cls(np.tile(one, (n_fibres, 1)), extrinsic,
                   np.zeros((n_controls, 6 if config.pose_corrections else 3), bool))

    def extrinsic_noise(self, R_body_lidar: np.ndarray):
        """Gaussian noise on the Pose3 tangent [w, v] (lidar axes) for body-axes sigmas."""
        to_tangent = tangent_to_axes(R_body_lidar).T
        return gtsam.noiseModel.Gaussian.Covariance(to_tangent @ np.diag(self.extrinsic ** 2) @ to_tangent.T)


def holding(priors: Priors, names: list[str]) -> Priors:
    """Priors with the named parameters' sigmas shrunk to HELD_SIGMA (held at nominal)."""
    intrinsic, extrinsic, control = priors.intrinsic.copy(), priors.extrinsic.copy(), priors.control_held.copy()
    for name in names:
        owner, parameter = name.split(".")
        index = int(owner.split("_")[1]) if "_" in owner else 0
        if owner.startswith("fibre_"):
            intrinsic[index, INTRINSIC_NAMES.index(parameter)] = HELD_SIGMA
        elif owner == "extrinsic":
            extrinsic[EXTRINSIC_NAMES.index(parameter)] = HELD_SIGMA
        else:
            column = CONTROL_NAMES.index(parameter) - (6 - control.shape[1])
            control[index, column] = True
    return replace(priors, intrinsic=intrinsic, extrinsic=extrinsic, control_held=control)


def energy_cm2(p_m: np.ndarray, m_m: np.ndarray, pairs: Correspondences) -> tuple[float, float]:
    """(J [cm^2], weight sum) of eq. 4.4 for the paired world points p, m (K,3) [m], with the
    correspondences' fixed normals and weights."""
    d = np.einsum("ni,ni->n", pairs.normal, p_m - m_m)
    weight_sum = float(pairs.weight.sum())
    return float((pairs.weight * d * d).sum() / weight_sum * 1e4), weight_sum


def build_graph(data: ReturnData, estimate: Estimate, pairs: Correspondences, config: CalibrationConfig,
                estimates: tuple[bool, bool, bool], nominal_extrinsic: gtsam.Pose3, priors: Priors,
                damped: bool = True, effects=None, blocks: list[tuple[np.ndarray, Block]] | None = None,
                lock: gtsam.CustomFactor | None = None):
    """One graph: a block factor per fibre of p and window of config.block_controls control
    intervals of p (per window only when the intrinsics are not estimated), plus priors.

    damped adds a prior at the current estimate on every key (sigmas step_sigma_m/deg): one outer
    iteration cannot run far along directions the current pairs barely see. It leaves the fixed
    point unchanged (at convergence the estimate stops moving) and is left out when sigmas are
    computed. effects (graphcal.diagnosis): candidate effect keys added to every block, with their
    values and priors. blocks: make_blocks' answer for these arguments, when the caller has it. lock: the
    factor that holds the weak directions at their nominal value (weak_directions.lock_factor), or None."""
    robust = None
    if config.robust != "none":
        scheme = gtsam.noiseModel.mEstimator.Base.ReweightScheme.Scalar
        create = {"huber": gtsam.noiseModel.mEstimator.Huber, "cauchy": gtsam.noiseModel.mEstimator.Cauchy}
        robust = create[config.robust].Create(config.robust_k, scheme)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    if blocks is None:
        blocks = make_blocks(data, estimate, pairs, config, estimates, effects)
    for _, block in blocks:
        graph.add(make_factor(block, compressed=robust is None, robust=robust))
    if effects is not None:
        effects.add_to(graph, values)
    if lock is not None:
        graph.add(lock)
    add_priors(graph, values, data, estimate, config, estimates, nominal_extrinsic, priors, damped,
                float(pairs.weight.sum()))
    return graph, values


def plane_model_sigma_m(pairs: Correspondences, config: CalibrationConfig) -> np.ndarray | float:
    """Each pair's plane-model sigma [m] for its incidence sigma: the out-of-plane scatter of p's
    neighbourhood (docs/math.md "Observability"), where the features follow the fit; 0 on fixed pairs
    (config.fixed_association), whose features stay those of the start: their scatter there holds the
    start's own errors between rings, which the fit is to remove, and would weigh those pairs down."""
    if config.fixed_association or pairs.out_of_plane_m is None:
        return 0.0
    return pairs.out_of_plane_m


def pose_sigma_m(data: ReturnData, estimate: Estimate, pairs: Correspondences) -> np.ndarray:
    """Each pair's sigma [m] from the recorded trajectory's white noise (data.pose_noise;
    factors.point_to_plane.pose_noise_sigma_m), p and m at the estimate."""
    noise = data.pose_noise
    if not noise.interval_s > 0:
        return np.zeros(len(pairs))
    p, m = pairs.index_p, pairs.index_m
    points = world_at(data, estimate, False, np.r_[p, m])
    return pose_noise_sigma_m(pairs.normal, points[:len(p)] - data.X_nav[p], points[len(p):] - data.X_nav[m],
                              data.time_s[p] - data.time_s[m], noise.interval_s, noise.position_m, noise.attitude_rad)


def make_blocks(data: ReturnData, estimate: Estimate, pairs: Correspondences, config: CalibrationConfig,
                estimates: tuple[bool, bool, bool], effects=None) -> list[tuple[np.ndarray, Block]]:
    """The block factors' data (see build_graph), each with its rows in pairs; effects.terms(p_rows,
    m_rows) gives each block's candidate effects (None: none)."""
    est_int, est_ext, est_traj = estimates
    pose = config.pose_corrections
    ref = data.sensor.reference_fibre
    normal_lidar = normals_to_lidar(data.returns(pairs.index_p), estimate.extrinsic.rotation().matrix(),
                                    corrections_at(estimate, data.control[pairs.index_p], pose), pairs.normal)
    fi, fj = data.fibre[pairs.index_p], data.fibre[pairs.index_m]
    cp, cm = data.control[pairs.index_p], data.control[pairs.index_m]
    sigma = np.full(len(pairs), config.sigma0_m)
    if config.pair_noise == "incidence":
        sigma = incidence_sigma_m(pairs.normal, rays_at(data, estimate, pairs.index_p),
                                  rays_at(data, estimate, pairs.index_m), config.sigma0_m,
                                  np.hypot(plane_model_sigma_m(pairs, config), pose_sigma_m(data, estimate, pairs)))
    intrinsic_key = np.array([NO_KEY if f == ref else I(f) for f in range(data.sensor.n_fibres)], np.int64)
    control_key = np.array([X(c) for c in range(len(data.control_times_s))], np.int64)
    blocks = []
    for rows in block_rows(fi if est_int else np.zeros_like(fi), cp // config.block_controls if est_traj else 0 * cp):
        p, m = pairs.index_p[rows], pairs.index_m[rows]
        keys = BlockKeys.of(len(rows), extrinsic=E(0) if est_ext else None,
                            intrinsic_p=intrinsic_key[fi[rows]] if est_int else None,
                            intrinsic_m=intrinsic_key[fj[rows]] if est_int else None,
                            p_lo=control_key[cp[rows]] if est_traj else None,
                            p_hi=control_key[cp[rows] + 1] if est_traj else None,
                            m_lo=control_key[cm[rows]] if est_traj else None,
                            m_hi=control_key[cm[rows] + 1] if est_traj else None)
        if not keys.unique and effects is None:
            continue
        offsets_p, offsets_m = estimate.offsets[data.fibre[p]], estimate.offsets[data.fibre[m]]
        p_returns, m_returns, held = data.returns(p), data.returns(m), (None, None)
        if pairs.shift_p_m is not None:
            (p_returns, p_held), (m_returns, m_held) = (on_stand_ins(p_returns, offsets_p, pairs.shift_p_m[rows]),
                                                         on_stand_ins(m_returns, offsets_m, pairs.shift_m_m[rows]))
            held = p_held, m_held
        block = Block(p=p_returns, m=m_returns, normal=normal_lidar[rows], weight=pairs.weight[rows],
                      keys=keys, pose_corrections=pose,
                      fixed=FixedValues(offsets_p, offsets_m, estimate.extrinsic),
                      sigma0_m=sigma[rows], effects=None if effects is None else effects.terms(p, m),
                      p_held_l=held[0], m_held_l=held[1])
        blocks.append((rows, block))
    return blocks


def add_priors(graph, values, data: ReturnData, estimate: Estimate, config: CalibrationConfig, estimates,
                nominal_extrinsic: gtsam.Pose3, priors: Priors, damped: bool, weight_sum: float) -> None:
    """Values and priors of the estimated keys (and the damping priors, see build_graph)."""
    est_int, est_ext, est_traj = estimates
    ref = data.sensor.reference_fibre
    step_m, step_rad = config.step_sigma_m, np.radians(config.step_sigma_deg)
    if est_int:
        for fibre in range(data.sensor.n_fibres):
            if fibre != ref:
                values.insert(I(fibre), estimate.offsets[fibre])
                graph.add(gtsam.PriorFactorVector(I(fibre), np.zeros(4),
                                                  gtsam.noiseModel.Diagonal.Sigmas(priors.intrinsic[fibre])))
                if damped:
                    graph.add(gtsam.PriorFactorVector(I(fibre), estimate.offsets[fibre], gtsam.noiseModel.Diagonal.Sigmas(
                        np.array([step_m, step_rad, step_rad, step_m]))))
    if est_ext:
        values.insert(E(0), estimate.extrinsic)
        graph.add(gtsam.PriorFactorPose3(E(0), nominal_extrinsic,
                                         priors.extrinsic_noise(nominal_extrinsic.rotation().matrix())))
        if damped:
            graph.add(gtsam.PriorFactorPose3(E(0), estimate.extrinsic, gtsam.noiseModel.Diagonal.Sigmas(
                np.r_[np.full(3, step_rad), np.full(3, step_m)])))
    if est_traj:
        add_trajectory(graph, values, estimate, config, control_prior_sigma(config, weight_sum), priors, damped)


def block_rows(fibre_p: np.ndarray, window: np.ndarray, max_rows: int = MAX_BLOCK_ROWS) -> list[np.ndarray]:
    """Pair indices of each block: the pairs of one fibre of p and one window of p's control
    intervals, in chunks of at most max_rows (few large blocks: each block is one Python callback)."""
    if not len(fibre_p):
        return []
    group = fibre_p.astype(np.int64) * (int(window.max()) + 1) + window
    order = np.argsort(group, kind="stable")
    bounds = np.flatnonzero(np.r_[True, np.diff(group[order]) != 0, True])
    return [chunk for start, stop in itertools.pairwise(bounds)
            for chunk in np.array_split(order[start:stop], -(-(stop - start) // max_rows))]


def control_prior_sigma(config: CalibrationConfig, weight_sum: float) -> float:
    """sigma [m, or rad x 1 m] of E_def's prior on each control correction: eq. 5.4 adds
    lambda_rigid |dX|^2 to the normalised energy J [m^2], and the graph's cost is W J / sigma0^2
    (W the weight sum of the pairs)."""
    return config.sigma0_m / np.sqrt(config.lambda_rigid * max(weight_sum, 1.0))


def add_trajectory(graph, values, estimate: Estimate, config: CalibrationConfig, sigma: float, priors: Priors,
                    damped: bool) -> None:
    """Control corrections and E_def (eq. 5.3) or Monnier's successive differences."""
    pose = config.pose_corrections
    width = 6 if pose else 3
    noise = gtsam.noiseModel.Isotropic.Sigma(width, sigma)  # rotations: rad x 1 m
    step = gtsam.noiseModel.Diagonal.Sigmas(np.r_[np.full(3, np.radians(config.step_sigma_deg)),
                                                  np.full(3, config.step_sigma_m)] if pose
                                            else np.full(3, config.step_sigma_m))
    prior = (lambda c, n: gtsam.PriorFactorPose3(X(c), gtsam.Pose3(), n)) if pose else \
        (lambda c, n: gtsam.PriorFactorPoint3(X(c), np.zeros(3), n))
    for c, correction in enumerate(estimate.corrections):
        values.insert(X(c), correction if pose else correction.translation())
        if damped:
            graph.add(gtsam.PriorFactorPose3(X(c), correction, step) if pose
                      else gtsam.PriorFactorPoint3(X(c), correction.translation(), step))
        if config.deformation == "prior" or c == 0:
            graph.add(prior(c, noise))
        if config.deformation == "monnier" and c > 0:
            graph.add(gtsam.BetweenFactorPose3(X(c - 1), X(c), gtsam.Pose3(), noise) if pose
                      else gtsam.BetweenFactorPoint3(X(c - 1), X(c), np.zeros(3), noise))
        if priors.control_held[c].any():
            graph.add(prior(c, gtsam.noiseModel.Diagonal.Sigmas(np.where(priors.control_held[c], HELD_SIGMA, 1e6))))


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


# LM's damping bound: the Hessian's diagonal spans from held priors (1/HELD_SIGMA^2 = 1e14) to loose ones
LAMBDA_UPPER_BOUND = 1e12


def levenberg_marquardt(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, iterations: int) -> gtsam.Values:
    """GTSAM's Levenberg-Marquardt with damping scaled by the Hessian's diagonal. With GTSAM's default
    (lambda times the identity, lambda <= 1e5) a graph whose diagonal reaches 1e14 (a held parameter
    beside millimetre-sharp ones) gets Gauss-Newton steps whatever lambda, and when that step overshoots
    LM rejects every lambda and returns the values unchanged: measured on diagnose's refit with a
    pitched head (time offset stuck at 0, with this damping 5.14 ms for a true 5 ms)."""
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(iterations)
    params.setDiagonalDamping(True)
    params.setlambdaUpperBound(LAMBDA_UPPER_BOUND)
    return gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()


def features_at(points_m: np.ndarray, config: CalibrationConfig) -> Features:
    """local_features of the points [m] with config's radius, neighbours and voxel size."""
    return local_features(points_m, config.feature_radius_m, config.feature_neighbours, config.feature_voxel_m)


class FeatureCache:
    """The features of a calibration's cloud, computed again only once they may have changed by more
    than config.refresh_above_m [m] (moved_m) since they were: the outer loop, the observability probe and the final
    fit share them (each computation is a neighbourhood search and an eigen-decomposition at every return)."""

    def __init__(self, config: CalibrationConfig):
        self.config, self.points_m, self.features = config, None, None

    def at(self, points_m: np.ndarray) -> tuple[Features, bool]:
        """(features for the points [m], whether they were computed now)."""
        if moved_m(points_m, self.points_m, self.config.feature_radius_m) <= self.config.refresh_above_m:
            return self.features, False
        self.points_m, self.features = points_m, features_at(points_m, self.config)
        return self.features, True


@dataclass(frozen=True)
class Association:
    """What one association step needs besides the points: fixed across outer iterations."""

    neighbours: dict
    candidates: np.ndarray
    seed: int

    @classmethod
    def of(cls, data: ReturnData, config: CalibrationConfig) -> Association:
        candidates = _candidates(data, CANDIDATES_PER_PAIR * config.max_pairs_per_fibre_pair,
                                 np.random.default_rng(config.seed))
        return cls(neighbour_fibres(data.sensor.elevation_deg, config.neighbours), candidates, config.seed)

    def pairs(self, points_m: np.ndarray, fibre: np.ndarray, features, gate_m: float,
              config: CalibrationConfig, sight: Sight | None, phase: str = "fine") -> Correspondences:
        """The same subsample of pairs for the same cloud (a fresh seeded draw each time); sight: the
        returns' lines of sight and stand-ins (sight_at), or None for plain nearest returns; in the coarse
        phase, only those within_spread."""
        pairs = associate(points_m, fibre, features, self.neighbours, gate_m, config.min_planarity,
                         np.cos(np.radians(config.max_normal_angle_deg)), config.max_plane_distance_m,
                         config.max_pairs_per_fibre_pair,
                         np.random.default_rng(self.seed), self.candidates, sight)
        return within_spread(pairs, points_m, config.sigma0_m) if phase == "coarse" else pairs


def strict_pairs(data: ReturnData, estimate: Estimate, config: CalibrationConfig,
                 cache: FeatureCache | None = None) -> tuple[np.ndarray, Correspondences]:
    """(world points [m], pairs) at an estimate with the strict settings of the fine phase."""
    fine = config.fine()
    points = world_at(data, estimate, config.pose_corrections)
    sight = sight_at(data, estimate, points)
    features = (cache or FeatureCache(config)).at(points)[0]
    return points, Association.of(data, fine).pairs(points, data.fibre, features, fine.fine_gate_m, fine, sight)


PHASES = ("coarse", "fine")


def solve_stage(data: ReturnData, estimate: Estimate, config: CalibrationConfig, stage: str,
                estimates: tuple[bool, bool, bool], nominal_extrinsic: gtsam.Pose3, priors: Priors,
                history: History, quiet: bool = False, fixed_pairs: Correspondences | None = None,
                phases: tuple[str, ...] = PHASES, cache: FeatureCache | None = None,
                max_iterations: int | None = None, lock: gtsam.CustomFactor | None = None) -> Estimate:
    """Outer iterations of one stage (which parameter groups move: estimates): coarse phase (its own
    pair subsample, config.coarse()) until max |dX| < fine_below_m, then fine phase until max |dX| <
    tolerance, a plateau of J, or n_max (max_iterations, else config.max_outer_iterations: outer
    iterations of both phases together). phases: the phases to run (("coarse",): stop at the
    switch; ("fine",): start there). fixed_pairs
    (config.fixed_association): the fine phase only, every outer iteration on these pairs and normals.
    Features are refreshed every refresh_every (K) outer iterations, when the cloud has moved (cache).
    lock: the factor holding the weak directions at nominal (weak_directions.lock_factor), or None."""
    pose = config.pose_corrections
    fine = fixed_pairs is not None or phases[0] == "fine"
    n_max = config.max_outer_iterations if max_iterations is None else max_iterations
    if (fine and "fine" not in phases) or n_max < 1:
        return estimate
    everything = data
    shared = cache = cache or FeatureCache(config)
    phase = "fine" if fine else "coarse"
    data, settings = phase_data(data, config, phase)
    if data is not everything:  # the coarse subsample has its own features
        cache = FeatureCache(config)
    gate = settings.gate_start_m
    association = Association.of(data, settings)
    features, refreshed, points = None, False, None
    fine_energies = []
    since_refresh = config.refresh_every
    for _ in progress(range(n_max), f"calibrating ({stage})", total=n_max, quiet=quiet):
        points = world_at(data, estimate, pose) if points is None else points
        sight = None if fixed_pairs is not None else phase_sight(data, estimate, points, phase)
        if fixed_pairs is None and (features is None or since_refresh >= config.refresh_every):
            features, refreshed = cache.at(points)
            since_refresh = 0 if refreshed else since_refresh
        since_refresh += 1
        pairs = fixed_pairs if fixed_pairs is not None else association.pairs(points, data.fibre, features, gate,
                                                                                settings, sight, phase)
        before, weight_sum = energy_cm2(points[pairs.index_p], points[pairs.index_m], pairs)
        graph, values = build_graph(data, estimate, pairs, settings, estimates, nominal_extrinsic, priors, lock=lock)
        updated = read_back(levenberg_marquardt(graph, values, config.lm_iterations), estimate, estimates, data, pose)
        step = step_size(estimate, updated)
        points = world_at(data, updated, pose)  # the next iteration's too
        after, _ = energy_cm2(points[pairs.index_p], points[pairs.index_m], pairs)
        history.add(mode=stage, iteration=len(history.rows), phase=phase, energy_cm2=before,
                    energy_after_cm2=after, weight_sum=weight_sum, pairs=len(pairs), gate_m=gate, max_step=step,
                    refreshed=refreshed, stop="")
        estimate, refreshed = updated, False
        if phase == "fine":
            fine_energies.append(before)
            if step < config.tolerance_m or on_plateau(fine_energies, config.plateau_iterations,
                                                       config.plateau_improvement):
                history.rows[-1]["stop"] = "converged"
                break
        if phase == "coarse" and step < config.fine_below_m:
            if "fine" not in phases:
                history.rows[-1]["stop"] = "coarse done"
                break
            phase, cache = "fine", shared
            data, settings = phase_data(everything, config, phase)
            gate = settings.gate_start_m
            association, since_refresh, features, points = Association.of(data, settings), config.refresh_every, None, None
        elif phase == "coarse":
            gate = min(gate * config.gate_growth, config.gate_max_m)
    else:
        if history.rows:
            history.rows[-1]["stop"] = "cap"
    return estimate


SPREAD_GATE = 10.0  # coarse phase: a pair is kept within this many robust sigmas of all pairs' distances


def within_spread(pairs: Correspondences, points_m: np.ndarray, floor_m: float) -> Correspondences:
    """The coarse pairs whose distance to the plane at p, |n.(p - m)| [m], is within SPREAD_GATE robust
    sigmas (1.4826 x the median |n.(p - m)| over all pairs) or within SPREAD_GATE x floor_m.

    The coarse gates are loose (up to 1 m, normals within 30 deg, no plane-distance gate) so that a start
    far from the truth finds pairs at all; they also pair returns up to a metre apart on surfaces that are
    planes only over centimetres (a pole, a car's flank, the corner of a building), and those pairs'
    distances pull the offsets even at the truth: from the true calibration of a level head in a box
    street, one coarse step at the 1 m gate moved the elevations 2.6 deg (RMS) without noise (J 11 cm2
    against 0.15 at the 0.3 m gate), and the outer loop collapsed the fibres. A calibration or trajectory
    that is wrong spreads every pair's distance (the robust sigma grows with it, far from the truth the gate
    keeps them); the pairs on a curved surface are the outliers of a cloud that is already sharp."""
    if not len(pairs):
        return pairs
    distance = np.abs(np.einsum("ni,ni->n", pairs.normal, points_m[pairs.index_p] - points_m[pairs.index_m]))
    spread = 1.4826 * float(np.median(distance))
    return pairs.take(distance <= SPREAD_GATE * max(spread, floor_m))


def phase_sight(data: ReturnData, estimate: Estimate, points_m: np.ndarray, phase: str) -> Sight | None:
    """What the association of a phase chooses m by: stand-ins (sight_at) in the fine phase; plain
    nearest returns in the coarse phase, which only has to reach the basin (and whose subsample leaves
    most returns without firing neighbours near enough for a stand-in)."""
    return sight_at(data, estimate, points_m) if phase == "fine" else None


def phase_data(data: ReturnData, config: CalibrationConfig, phase: str) -> tuple[ReturnData, CalibrationConfig]:
    """The returns and settings of a phase: the fine phase's are all returns and config.fine(); the
    coarse phase's a seeded random subset of config.coarse_max_points returns and config.coarse()."""
    if phase == "fine":
        return data, config.fine()
    if config.coarse_max_points is not None:
        data = data.sample(config.coarse_max_points, np.random.default_rng(config.seed))
    return data, config.coarse()


def moved_m(points_m: np.ndarray, before_m: np.ndarray | None, radius_m: float) -> float:
    """How much the features of a cloud [m] may have changed since it was at before_m: the largest
    displacement of a point once the best rigid motion is removed (the shape's change), or the angle
    of that motion times radius_m (it turns the normals, seen over a neighbourhood of radius_m),
    whichever is larger. A common translation changes nothing; inf when there is no before, or
    another cloud."""
    if before_m is None or before_m.shape != points_m.shape:
        return np.inf
    now, then = points_m - points_m.mean(axis=0), before_m - before_m.mean(axis=0)
    rotation, _ = Rotation.align_vectors(now, then)  # now ~ R then (Kabsch)
    moved = now - rotation.apply(then)
    shape_m = float(np.sqrt(np.einsum("ni,ni->n", moved, moved).max(initial=0.0)))
    return max(shape_m, rotation.magnitude() * radius_m)


def on_plateau(energies: list[float], iterations: int, improvement: float) -> bool:
    """True when none of the last `iterations` energies fell below (1 - improvement) times the
    lowest one before them: J has stopped falling (it only jitters with the association)."""
    if len(energies) <= iterations:
        return False
    return min(energies[-iterations:]) > (1.0 - improvement) * min(energies[:-iterations])


def hold_at_nominal(estimate: Estimate, priors: Priors, nominal_extrinsic: gtsam.Pose3) -> Estimate:
    """The estimate with every held parameter (prior sigma HELD_SIGMA) set back to nominal."""
    offsets = np.where(priors.intrinsic <= HELD_SIGMA, 0.0, estimate.offsets)
    held_ext = priors.extrinsic <= HELD_SIGMA
    extrinsic = estimate.extrinsic
    if held_ext.any():
        to_body = tangent_to_axes(nominal_extrinsic.rotation().matrix())
        body = to_body @ nominal_extrinsic.localCoordinates(estimate.extrinsic)
        body[held_ext] = 0.0
        extrinsic = nominal_extrinsic.retract(to_body.T @ body)
    corrections = tuple(_zero_components(c, held) for c, held in zip(estimate.corrections, priors.control_held))
    return replace(estimate, offsets=offsets, extrinsic=extrinsic, corrections=corrections)


def _zero_components(correction: gtsam.Pose3, held: np.ndarray) -> gtsam.Pose3:
    if not held.any():
        return correction
    tangent = np.r_[gtsam.Rot3.Logmap(correction.rotation()), correction.translation()]
    tangent[-len(held):][held] = 0.0
    return gtsam.Pose3(gtsam.Rot3.Expmap(tangent[:3]), tangent[3:])


def _candidates(data: ReturnData, per_fibre: int, rng: np.random.Generator) -> np.ndarray:
    """Up to per_fibre random returns of each fibre: the p's of eq. 4.4."""
    rows = []
    for fibre in np.unique(data.fibre):
        of_fibre = np.flatnonzero(data.fibre == fibre)
        if len(of_fibre) > per_fibre:
            of_fibre = np.sort(rng.choice(of_fibre, per_fibre, replace=False))
        rows.append(of_fibre)
    return np.sort(np.concatenate(rows))
