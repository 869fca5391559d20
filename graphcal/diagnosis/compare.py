"""A recording against a simulation of the same drive (same trajectory, same scene, nominal physics):
which left-out effect explains their difference.

Both are georeferenced with their nominal model. Each return p of the recording is paired with the
nearest simulated return m on a planar patch; the simulated cloud is a fixed map, so only p moves
with the candidates: r = n . (p(theta) - m) / sigma0. Every candidate is score-tested as in
graphcal.diagnosis.score (no calibration parameter: both sides have the same model), with the
same cluster-robust variance factor and held-out time blocks; the base holds only a common
translation of the recording against the simulation. The significant, plausible ones are reported
strongest first with their least-squares size.
"""

from __future__ import annotations

import time

import numpy as np
from scipy.spatial import cKDTree

from factors.channels import Channels, channel_jacobians
from factors.effects import CANDIDATES, candidate
from factors.world_point import Corrections, Placed, Turn, world_normals, world_points
from graphcal.calibration.association import Features
from graphcal.calibration.config import CalibrationConfig
from graphcal.calibration.returns import Estimate, initial_estimate, prepare, sight_at, world_at
from graphcal.calibration.pairing import features_at
from graphcal.diagnosis.context import EffectModel, ReturnContext, world_with_effects
from graphcal.diagnosis.diagnose import (
    DEFAULT_SEPARATING_DATA,
    NOT_SEPARABLE_CORRELATION,
    SEPARATING_DATA,
    Diagnosis,
    _row,
    display,
    plausible,
)
from graphcal.diagnosis.fit import BLOCK_S, VOXEL_M
from graphcal.diagnosis.rescan import with_controls
from graphcal.diagnosis.score import (
    Linearisation,
    linearisation_of_rows,
    score_candidates,
    separation,
)
from graphcal.recording.directory import Recording

GATE_M = 0.3
MAX_EFFECTS = 3
MIN_PLANARITY = 0.7
SIGMA0_M = 0.01
REFINE_ITERATIONS = 6
REFINED_BELOW = 0.05  # the refinement stops when every step is below this many sigmas
REFINED_RELATIVE = 1e-3  # or below this fraction of the parameter


def compare(recording: Recording, simulation: Recording, max_points: int | None = 200_000,
            candidates: list[str] | None = None, seed: int = 0, estimate: Estimate | None = None) -> Diagnosis:
    """Name the effect that explains recording - simulation (see the module docstring); both placed
    with estimate's offsets and extrinsic (default: the nominal model)."""
    started = time.perf_counter()
    rng = np.random.default_rng(seed)
    data = prepare(recording, np.inf, max_points, rng)
    sim = prepare(simulation, np.inf, None if max_points is None else 4 * max_points, rng)
    estimate = initial_estimate(recording, data) if estimate is None else estimate
    points = world_at(data, with_controls(estimate, data), pose=False)
    sim_points = world_at(sim, with_controls(estimate, sim), pose=False) + sim.origin_m - data.origin_m
    # a moving simulation's features from every return, as for a noise-free head: with 0.1 m voxels (those of a
    # noisy head) the heading-bias recording of bench_diagnose named fibre_horizontal_offset before heading_bias
    settings = CalibrationConfig().for_sensor(sim.static, 0.0, one_viewpoint=sim.one_viewpoint)
    features = features_at(sim_points, settings.features)
    sim_tree = cKDTree(sim_points)
    rows, nearest, normal = _paired(points, sim_tree, features)
    context = ReturnContext.of(data, recording.world.poses, points, Features(normal, *(np.zeros(len(points)),) * 2),
                               estimate.extrinsic.translation(), sight_at(data, with_controls(estimate, data)))
    names = list(candidates or CANDIDATES)
    estimate = with_controls(estimate, data)
    r, J, columns = _linear_system(data, estimate, context, names, rows, normal[rows], sim_points[nearest[rows]])
    lin = _linearisation(r, J, columns, names, data.time_s[rows] - data.time_s[0], points[rows])
    translation = np.arange(J.shape[1] - 3, J.shape[1])
    before = _energy_cm2(r, J, translation)
    findings, not_separable, first, active, named = [], [], None, [], []
    while len(active) < MAX_EFFECTS:  # DIA without refits: the problem is linear, conditioning is exact
        remaining = [n for n in names if n not in active]
        tests = score_candidates(lin, remaining, remaining)
        if first is None:
            first = [_row(t, recording, len(names)) for t in sorted(tests.values(), key=lambda t: t.log10_p)]
        significant = [t for t in tests.values() if t.identifiable and t.significant(len(names))]
        eligible = sorted((t for t in significant if plausible(t, recording)), key=lambda t: -t.bic_gain)
        if not eligible:
            break
        test = eligible[0]
        for other in significant:
            rho = separation(lin, test.name, other.name, remaining) if other.name != test.name else 0.0
            if rho > NOT_SEPARABLE_CORRELATION:
                not_separable.append({"effects": sorted([test.name, other.name]), "correlation": rho,
                                      "named": test.name, "would_separate": SEPARATING_DATA.get(
                                          frozenset({test.name, other.name}), DEFAULT_SEPARATING_DATA)})
        active.append(test.name)
        named.append((test, _energy_cm2(r, J, np.concatenate([lin.effect_columns[n] for n in active] + [translation]))))
    sizes = _refined(data, estimate, context, [t for t, _ in named], sim_tree, sim_points, features)
    for (test, after), theta in zip(named, sizes):
        magnitude = candidate(test.name).magnitude_of(theta)
        findings.append({"effect": test.name, "magnitude": magnitude, "sigma": test.sigma,
                         "unit": candidate(test.name).unit, "parameters": theta.tolist(),
                         "statement": f"the recording differs from the simulation by {candidate(test.name).physics} "
                                      f"({test.name}: {display(test.name, magnitude)} ± "
                                      f"{display(test.name, test.sigma)}); modelling it lowers J against the "
                                      f"simulation from {before:.3g} to {after:.3g} cm²",
                         "absorbed_by": [], "mdb": test.mdb, "concealment_r2": test.concealment_r2,
                         "evidence": {"statistic": test.statistic, "dof": test.dof, "p_value": test.p_value,
                                      "log10_p": test.log10_p, "bic_gain": test.bic_gain},
                         "energy_cm2": {"before": before, "after": after, "held_out_before": test.held_out_cm2[0],
                                        "held_out_after": test.held_out_cm2[1]}})
    return Diagnosis(findings, not_separable, [], [], first, [], {"before": before}, time.perf_counter() - started)


def _paired(points_m: np.ndarray, sim_tree: cKDTree, features: Features) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rows of the points paired, each point's nearest simulated return, normals (N,3), zero where unpaired):
    the nearest simulated return within GATE_M on a planar patch."""
    distance, nearest = sim_tree.query(points_m, distance_upper_bound=GATE_M, workers=-1)
    found = np.isfinite(distance)
    nearest = np.where(found, nearest, 0)
    rows = np.flatnonzero(found & (features.planarity[nearest] >= MIN_PLANARITY))
    normal = np.zeros_like(points_m)
    normal[rows] = features.normal[nearest[rows]]
    return rows, nearest, normal


def _refined(data, estimate: Estimate, context: ReturnContext, tests: list, sim_tree: cKDTree,
             sim_points: np.ndarray, features: Features) -> list[np.ndarray]:
    """The named effects' parameters, from their linear sizes (tests) refined by Gauss-Newton with the
    recording re-paired at every step, as ICP does: a large effect (returns stamped with their
    revolution's start move up to a metre) pairs many returns with the wrong simulated ones at the
    nominal model, and the linear size falls short (-36 % for the revolution stamps, bench_diagnose)."""
    names = [t.name for t in tests]
    thetas = [np.asarray(t.theta, dtype=np.float64) for t in tests]
    for _ in range(REFINE_ITERATIONS if names else 0):
        points = world_with_effects(data, estimate, False, EffectModel(tuple(names), dict(zip(names, thetas)), context))
        rows, nearest, normal = _paired(points, sim_tree, features)
        r, J, columns = _linear_system(data, estimate, context, names, rows, normal[rows], sim_points[nearest[rows]],
                                       points[rows])
        step = np.linalg.lstsq(J, -r, rcond=None)[0]  # the candidates' columns and the common translation
        thetas = [theta + step[columns[n]] for n, theta in zip(names, thetas)]
        if all(np.all(np.abs(step[columns[n]]) <= _tolerance(t, theta)) for n, t, theta in zip(names, tests, thetas)):
            break
    return thetas


def _tolerance(test, theta: np.ndarray) -> np.ndarray:
    """A refinement step small enough to stop: REFINED_BELOW of the parameters' sigmas, or REFINED_RELATIVE
    of their size where the robust covariance gives no sigma (a diagonal at or below zero)."""
    sigma = np.sqrt(np.clip(np.diag(test.covariance), 0.0, None))
    return np.maximum(REFINED_BELOW * sigma, REFINED_RELATIVE * np.abs(theta))


def _energy_cm2(r: np.ndarray, J: np.ndarray, columns: np.ndarray) -> float:
    """J [cm^2] of the pairs once the given columns are fitted (least squares)."""
    step = np.linalg.lstsq(J[:, columns], -r, rcond=None)[0]
    return float(np.sum((r + J[:, columns] @ step) ** 2)) * SIGMA0_M ** 2 / len(r) * 1e4


def _linear_system(data, estimate, context: ReturnContext, names, rows, normal_w, m_w, p_at=None):
    """Whitened residuals (K,), their Jacobian (K, sum of dims) on the candidates, and each candidate's
    columns, at the nominal model (every candidate at zero); p_at: the recording's points [m] at which
    the residuals are taken instead (the candidates at some size; the Jacobian stays the nominal's)."""
    returns = data.returns(rows)
    zero = np.zeros((len(rows), 3))
    corrections = Corrections(zero, zero)
    R_E, t_E = estimate.extrinsic.rotation().matrix(), estimate.extrinsic.translation()
    offsets = estimate.offsets[data.fibre[rows]]
    p_w, J_world = world_points(returns, offsets, R_E, t_E, corrections)
    bases = [candidate(n).basis(context.context(rows)) for n in names]
    motion = context.motion(rows)
    channels = Channels.of(tuple(bases), [np.zeros(b.dim) for b in bases], len(rows))
    n_lidar = np.einsum("nji,nj->ni", returns.R_nav, normal_w) @ R_E
    n_w, _ = world_normals(returns, R_E, corrections, n_lidar, jacobians=False)
    at = channel_jacobians(Placed(returns, offsets, R_E, corrections, Turn(None), p_w, J_world), motion, channels)
    r = np.einsum("ni,ni->n", n_w, (p_w if p_at is None else p_at) - m_w) / SIGMA0_M
    parts = [np.einsum("ni,nij->nj", n_w, at.of_candidate(b)) / SIGMA0_M for b in bases]
    starts = np.cumsum([0] + [p.shape[1] for p in parts])
    # the base: a common translation of the recording against the simulation (a datum shift; it also
    # takes the centre of a scaled trajectory, which the position candidates scale about the mean)
    return (r, np.hstack(parts + [n_w / SIGMA0_M]),
            {n: np.arange(a, b) for n, a, b in zip(names, starts[:-1], starts[1:])})


def _linearisation(r, J, columns, names, time_s, points_m) -> Linearisation:
    block = np.floor((time_s - time_s.min()) / BLOCK_S).astype(np.int64)
    _, cluster = np.unique(np.column_stack([block, np.floor(points_m / VOXEL_M).astype(np.int64)]), axis=0,
                           return_inverse=True)
    labels = [n if len(columns[n]) == 1 else f"{n}[{j}]" for n in names for j in range(len(columns[n]))]
    labels += [f"common_translation_{axis}_m" for axis in "xyz"]
    return linearisation_of_rows(r, J, labels, columns, cluster.ravel(), block, SIGMA0_M)
