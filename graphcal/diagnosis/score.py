"""Score (Rao / Lagrange-multiplier) tests of candidate effects at a fit, after Baarda and Teunissen's
DIA: each candidate's Jacobian is projected off the estimated parameters, its score tested with a
cluster-robust variance, its size estimated with a sigma and a minimal detectable bias (MDB), and
the parameter that was absorbing it named.

Notation: the graph linearised at the fit, in named coordinates (extrinsic in body axes), gives the
information L and vector eta (a Gauss-Newton step solves L d = eta). For base parameters b and a
candidate k (parameters theta_k = 0 at the fit):

    S = L_kk - L_kb L_bb^-1 L_bk          information on theta_k left once b is estimated
    u = eta_k - L_kb L_bb^-1 eta_b        score of theta_k projected off b
    theta_hat = S^-1 u,   T = u^T V^-1 u ~ chi2(d_k) under "no effect"

T = u^T S^-1 u / f, with f = tr(S^-1 V) / d_k the variance factor of the projected score: V is its
cluster-robust variance, the sum over clusters c (blocks of space and time) of u_c u_c^T with u_c
the projected score of the pairs in c, once the candidate is fitted (its own signal out). Residuals of neighbouring pairs share points and surfaces,
and sigma0 is a nominal noise: f takes both into account where u^T S^-1 u (the textbook statistic)
counts 10^5 correlated pairs as independent and flags everything. (f rather than the full V^-1:
V is poorly conditioned for a candidate of 32 parameters seen by a few hundred clusters.)
Concealment R^2 = 1 - S / L_kk: the share of the candidate's signature the base parameters mimic.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import gtsam
import numpy as np
from scipy import optimize, stats

from factors.discrepancy import is_discrepancy
from factors.effects import candidate
from factors.point_to_plane import jacobian_by_key, residuals
from graphcal.calibration.association import Correspondences
from graphcal.calibration.observability import (
    CONTROL_NAMES,
    EXTRINSIC_NAMES,
    INTRINSIC_NAMES,
    tangent_to_axes,
)
from graphcal.calibration.returns import Estimate
from graphcal.calibration.keys import E
from graphcal.calibration.problem import Problem
from graphcal.diagnosis.context import EffectModel

ALPHA = 1e-3  # family-wise false-alarm rate over the candidates
POWER = 0.8
IDENTIFIABLE_R2 = 0.995  # above this concealment the candidate is not tested: the model already has it
BLIND_INFORMATION = 1e-12  # a candidate's information below this share of the median parameter's: the data are blind
# an effect must explain at least this fraction of sigma0 (RMS over the pairs, beyond what the base
# absorbs) to count: on noise-free data the tests otherwise resolve the pipeline's own misfits (two
# effects named on 400 k noise-free returns). A concealed 0.08 deg eccentricity explains 0.3 mm (0.03)
PRACTICAL_FLOOR_SIGMA0 = 0.01
# a generic discrepancy (factors.discrepancy) must explain a tenth of sigma0: its flexible basis also fits the
# pipeline's own misfits (on a clean 300 k-return recording, 1 cm noise, an elevation-against-range curve explained
# 5.5 % of sigma0 and lowered held-out J by 0.4 %); a tenth of the noise is what moves a cloud visibly
DISCOVERY_FLOOR_SIGMA0 = 0.1
# the drive's time blocks fall in this many folds (block index modulo FOLDS, an even number: a fold keeps the
# parity that makes the held-out halves); the held-out drop's standard error is taken across them
FOLDS = 32


@functools.lru_cache(maxsize=64)
def noncentrality(dof: int, alpha: float = ALPHA, power: float = POWER) -> float:
    """lambda0 of the MDB: the non-centrality at which a chi2(dof) test of size alpha has the power
    asked (17.07 for one parameter at alpha 0.1 %, power 80 %)."""
    threshold = stats.chi2.isf(alpha, dof)
    return float(optimize.brentq(lambda lam: stats.ncx2.sf(threshold, dof, lam) - power, 1e-6, 1e4))


@dataclass(frozen=True)
class Linearisation:
    """The graph at a fit, in named coordinates: information (n,n) and vector (n,) of the whole graph
    (data and priors), the parameter name of each column, the columns of each effect, the data's rows
    in blocks made again at each call of row_blocks (cluster id (N,), Jacobian (N, w), whitened residual (N,),
    global columns (w,): kept, every block's Jacobian of every candidate's columns would hold gigabytes), the
    number of clusters, and per fold of the drive's time blocks (block index modulo FOLDS: a fold's blocks
    share the parity that makes the halves of the held-out tests) the data's information, vector, cost sum r^2
    and weight sum."""

    information: np.ndarray
    vector: np.ndarray
    names: list[str]
    effect_columns: dict
    row_blocks: Callable[[], Iterator[tuple]]
    n_clusters: int
    fold_information: np.ndarray
    fold_vector: np.ndarray
    fold_cost: np.ndarray
    fold_weight: np.ndarray
    sigma0_m: float

    @functools.cached_property
    def half_information(self) -> np.ndarray:
        return np.stack([self.fold_information[h::2].sum(axis=0) for h in (0, 1)])

    @functools.cached_property
    def half_vector(self) -> np.ndarray:
        return np.stack([self.fold_vector[h::2].sum(axis=0) for h in (0, 1)])

    @property
    def half_cost(self) -> np.ndarray:
        return np.array([self.fold_cost[h::2].sum() for h in (0, 1)])

    @property
    def half_weight(self) -> np.ndarray:
        return np.array([self.fold_weight[h::2].sum() for h in (0, 1)])

    @property
    def prior_information(self) -> np.ndarray:
        return self.information - self.half_information.sum(axis=0)

    @property
    def prior_vector(self) -> np.ndarray:
        return self.vector - self.half_vector.sum(axis=0)

    def energy_cm2(self, half: int, step: np.ndarray) -> float:
        """J [cm^2] of a half's pairs after the linear step (named coordinates); NaN for a half without pairs."""
        if self.half_weight[half] <= 0:
            return float("nan")
        cost = self.half_cost[half] - 2 * self.half_vector[half] @ step + step @ self.half_information[half] @ step
        return float(cost * self.sigma0_m ** 2 / self.half_weight[half] * 1e4)


def linearisation_of_rows(r: np.ndarray, A: np.ndarray, names: list[str], effect_columns: dict,
                          cluster: np.ndarray, block: np.ndarray, sigma0_m: float) -> Linearisation:
    """The Linearisation of a stacked least-squares problem without priors: whitened residuals (K,),
    their Jacobian (K, n), each column's name, the effects' columns, and per row its cluster and time
    block. Every row counts with weight 1 in J."""
    fold = (block - block.min()) % FOLDS
    g = -A * r[:, None]
    info = np.stack([A[fold == f].T @ A[fold == f] for f in range(FOLDS)])
    vector = np.stack([g[fold == f].sum(axis=0) for f in range(FOLDS)])
    cost = np.bincount(fold, weights=r * r, minlength=FOLDS)
    weight = np.bincount(fold, minlength=FOLDS).astype(np.float64)
    return Linearisation(info.sum(axis=0), vector.sum(axis=0), names, effect_columns,
                         lambda: iter([(cluster, A, r, np.arange(A.shape[1]))]), int(cluster.max()) + 1, info, vector,
                         cost, weight, sigma0_m)


def _key_names(key: int, width: int, model: EffectModel, pose: bool) -> list[str]:
    symbol = gtsam.Symbol(key)
    char, index = chr(symbol.chr()).upper(), symbol.index()
    if char == "I":
        return [f"fibre_{index}.{n}" for n in INTRINSIC_NAMES]
    if char == "E":
        return [f"extrinsic.{n}" for n in EXTRINSIC_NAMES]
    if char == "X":
        return [f"control_{index}.{n}" for n in (CONTROL_NAMES if pose else CONTROL_NAMES[3:])]
    name = model.names[index]
    return [name] if width == 1 else [f"{name}[{j}]" for j in range(width)]


def linearise(problem: Problem, estimate: Estimate, pairs: Correspondences, cluster: np.ndarray,
              block: np.ndarray) -> Linearisation:
    """Linearise the undamped graph with the problem's effects (candidates at zero, no prior on them) at
    the estimate; cluster (K,) and time block (K,) label each pair (its fold: the block modulo FOLDS). The
    pairs' blocks are made and linearised one at a time (every candidate's basis for every pair, kept, would
    hold gigabytes); the priors come from the graph without them."""
    fold = (block - (block.min() if len(block) else 0)) % FOLDS
    graph, values = problem.graph(estimate, pairs, damped=False, blocks=[])
    model, config = problem.effects, problem.config
    keys = list(values.keys())
    zero = values.zeroVectors()
    widths = {k: len(zero.at(k)) for k in keys}
    column = dict(zip(keys, np.r_[0, np.cumsum([widths[k] for k in keys])][:-1]))
    n = sum(widths.values())

    def columns_of(factor_keys) -> np.ndarray:
        return np.concatenate([np.arange(column[k], column[k] + widths[k]) for k in factor_keys])

    # tangent -> named coordinates: the extrinsic's tangent turned into body axes (orthogonal)
    to_named = np.eye(n)
    if E(0) in column:
        s = column[E(0)]
        to_named[s:s + 6, s:s + 6] = tangent_to_axes(estimate.extrinsic.rotation().matrix())
    names = [name for k in keys for name in _key_names(k, widths[k], model, config.trajectory.pose_corrections)]

    def row_blocks() -> Iterator[tuple]:
        """Each block's pairs: their rows in pairs, Jacobian in named coordinates, whitened residuals, columns."""
        for rows, factor_block in problem.each_block(estimate, pairs):
            r, A = residuals(factor_block, values)
            cols = columns_of(jacobian_by_key(factor_block, A))
            yield rows, A @ to_named[np.ix_(cols, cols)].T, r, cols  # block-diagonal: the block's columns stay its own

    fold_information, fold_vector = np.zeros((FOLDS, n, n)), np.zeros((FOLDS, n))
    fold_cost, fold_weight = np.zeros(FOLDS), np.zeros(FOLDS)
    for rows, A, r, cols in row_blocks():
        g = -A * r[:, None]  # each pair's contribution to eta
        for f in np.unique(fold[rows]):
            of = fold[rows] == f
            fold_information[f][np.ix_(cols, cols)] += A[of].T @ A[of]
            fold_vector[f, cols] += g[of].sum(axis=0)
        fold_cost += np.bincount(fold[rows], weights=r * r, minlength=FOLDS)
        fold_weight += np.bincount(fold[rows], weights=pairs.weight[rows], minlength=FOLDS)
    information, vector = fold_information.sum(axis=0), fold_vector.sum(axis=0)
    linear = graph.linearize(values)  # the priors (and lock, effects' priors): A^T A and A^T b in tangent coordinates
    for i in range(linear.size()):
        factor = linear.at(i)
        A, b = factor.jacobian()
        cols = columns_of(factor.keys())
        A_named = A @ to_named[np.ix_(cols, cols)].T
        information[np.ix_(cols, cols)] += A_named.T @ A_named
        vector[cols] += A_named.T @ b
    effect_columns = {name: np.arange(column[k], column[k] + model.dim(name)) for k, name in zip(model.keys, model.names)}
    n_clusters = int(cluster.max()) + 1 if len(cluster) else 0
    return Linearisation(information, vector, names, effect_columns,
                         lambda: ((cluster[rows], A, r, cols) for rows, A, r, cols in row_blocks()), n_clusters,
                         fold_information, fold_vector, fold_cost, fold_weight, config.weighting.sigma0_m)


def _solve(L: np.ndarray, B: np.ndarray) -> np.ndarray:
    """L^-1 B for a symmetric positive semi-definite L spanning many orders of magnitude (held
    parameters next to loose ones): scaled to a unit diagonal, then a pseudo-inverse by eigenvalues."""
    if L.size == 0:
        return np.zeros(B.shape)
    scale = 1.0 / np.sqrt(np.maximum(np.diag(L), 1e-300))
    w, V = np.linalg.eigh(L * np.outer(scale, scale))
    kept = w > w.max() * 1e-12
    inverse = (V[:, kept] / w[kept]) @ V[:, kept].T
    return scale[:, None] * (inverse @ (scale[:, None] * B)) if B.ndim == 2 else scale * (inverse @ (scale * B))


@dataclass(frozen=True)
class CandidateTest:
    """One candidate's test at a fit. theta (d,) and its robust covariance in the candidate's SI
    parameters; magnitude, sigma and mdb in its headline unit; statistic ~ chi2(dof) robust, with
    naive_statistic the textbook u^T S^-1 u (statistic x the variance factor); concealment R^2; absorbed_by: (parameter, correlation)
    of the base parameters most correlated with the estimate; held-out J [cm^2] without and with it
    (fit on one half of the drive's time blocks, evaluated on the other, both ways, averaged) and the
    standard error of their difference across the held-out time blocks."""

    name: str
    dof: int
    statistic: float
    p_value: float
    naive_statistic: float
    theta: np.ndarray
    covariance: np.ndarray
    magnitude: float
    sigma: float
    mdb: float
    concealment_r2: float
    absorbed_by: list
    held_out_cm2: tuple[float, float]
    n_clusters: int = 0
    explained_rms_m: float = 0.0
    sigma0_m: float = 1.0
    held_out_se_cm2: float = np.inf

    def significant(self, n_candidates: int, alpha: float = ALPHA, floor_sigma0: float | None = None) -> bool:
        """Bonferroni over the candidates, a positive BIC gain, confirmed on held-out data (held-out J
        drops by more than the drop's standard error across the held-out time blocks: with millions of
        returns a lower held-out J alone is found everywhere), and large enough to matter: it explains at
        least floor_sigma0 of sigma0 (None: the candidate's own, self.floor_sigma0)."""
        floor = self.floor_sigma0 if floor_sigma0 is None else floor_sigma0
        return bool(self.p_value < alpha / max(n_candidates, 1) and self.bic_gain > 0
                    and self.held_out_cm2[0] - self.held_out_cm2[1] > self.held_out_se_cm2
                    and self.explained_rms_m >= floor * self.sigma0_m)

    @property
    def floor_sigma0(self) -> float:
        """The share of sigma0 the candidate must explain to count (a discrepancy's is higher)."""
        return DISCOVERY_FLOOR_SIGMA0 if is_discrepancy(self.name) else PRACTICAL_FLOOR_SIGMA0

    @property
    def bic_gain(self) -> float:
        """T - d ln(C): the fit's gain less BIC's price of d parameters, C the number of independent
        clusters; ranks candidates of different sizes (a 32-parameter candidate soaks up part of
        any signal and its p-value alone would rank it too high)."""
        return float(self.statistic - self.dof * np.log(max(self.n_clusters, 2)))

    @property
    def identifiable(self) -> bool:
        return self.concealment_r2 <= IDENTIFIABLE_R2

    @property
    def log10_p(self) -> float:
        """log10 of the p-value, finite where the p-value underflows (the ranking key)."""
        return float(stats.chi2.logsf(self.statistic, self.dof) / np.log(10.0))


def _headline_sigma(name: str, theta: np.ndarray, covariance: np.ndarray) -> tuple[float, float]:
    """(sigma, mdb) of the headline magnitude: delta method along the estimate's direction."""
    magnitude = candidate(name).magnitude_of
    d = len(theta)
    norm = np.linalg.norm(theta)
    direction = theta / norm if norm > 0 else np.eye(d)[0]
    sigma_along = float(np.sqrt(max(direction @ covariance @ direction, 0.0)))
    step = direction * sigma_along
    sigma = abs(magnitude(step) - magnitude(np.zeros(d))) if d > 1 else abs(magnitude(step))
    mdb = abs(magnitude(direction * sigma_along * np.sqrt(noncentrality(d))))
    return float(sigma), float(mdb)


def wald_at_refit(value: np.ndarray, test: CandidateTest) -> tuple[float, float]:
    """(statistic, p-value) of an added effect at its refit: value (its SI parameters there) against
    its robust covariance there (test: score_candidate at the refit, the effect among the candidates):
    v^T C^-1 v ~ chi2(d) if the effect is not there. The score test judges a linear step from the
    fit without the effect; the re-solved fit (re-associated) can leave far less of it."""
    value = np.atleast_1d(np.asarray(value, dtype=np.float64))
    statistic = float(value @ _solve(test.covariance, value))
    return statistic, float(stats.chi2.sf(statistic, len(value)))


@dataclass(frozen=True)
class _Projection:
    """A candidate's columns k projected off the base columns at a fit: Xs = L_bb^-1 L_bk, the information left
    S, the projected score u, the concealment R^2 and theta = S^-1 u (None where nothing is left to test)."""

    name: str
    base: np.ndarray
    k: np.ndarray
    Xs: np.ndarray
    S: np.ndarray
    u: np.ndarray
    r2: float
    blind: bool

    @classmethod
    def of(cls, lin: Linearisation, name: str, candidates: list[str]) -> _Projection:
        k = lin.effect_columns[name]
        others = np.concatenate([lin.effect_columns[c] for c in candidates]) if candidates else np.zeros(0, int)
        base = np.setdiff1d(np.arange(len(lin.names)), others)
        L, eta = lin.information, lin.vector
        Xs = _solve(L[np.ix_(base, base)], L[np.ix_(base, k)])
        S = L[np.ix_(k, k)] - L[np.ix_(k, base)] @ Xs
        r2 = float(np.mean(1.0 - np.diag(S) / np.maximum(np.diag(L[np.ix_(k, k)]), 1e-300)))
        blind = bool(np.diag(L[np.ix_(k, k)]).max() <= BLIND_INFORMATION * np.median(np.diag(L)))
        return cls(name, base, k, Xs, S, eta[k] - Xs.T @ eta[base], r2, blind)

    @property
    def testable(self) -> bool:
        return not self.blind and self.r2 <= IDENTIFIABLE_R2

    @functools.cached_property
    def S_inv(self) -> np.ndarray:
        return np.linalg.pinv(self.S)

    @functools.cached_property
    def theta(self) -> np.ndarray:
        return self.S_inv @ self.u

    def untestable(self, lin: Linearisation) -> CandidateTest:
        """The test of a candidate the data are blind to (a time offset seen from a static sensor: absorbed by
        nothing) or that the base parameters mimic entirely (nothing left to test)."""
        d = len(self.k)
        nan = np.full(d, np.nan)
        absorbed = [] if self.blind else _absorbing(lin.information, self.base, self.k, self.Xs, self.S_inv,
                                                    np.ones(d), lin.names)
        return CandidateTest(self.name, d, 0.0, 1.0, 0.0, nan, np.full((d, d), np.nan), np.nan, np.nan, np.inf,
                             1.0 if self.blind else self.r2, absorbed, (np.nan, np.nan), lin.n_clusters)

    def test(self, lin: Linearisation, V: np.ndarray) -> CandidateTest:
        """The test with V, the cluster-robust variance of the projected score (_cluster_variances)."""
        S_inv, theta, u, d = self.S_inv, self.theta, self.u, len(self.k)
        factor = max(float(np.trace(S_inv @ V)) / d, 1e-12)
        statistic = float(u @ S_inv @ u) / factor
        covariance = S_inv * factor
        sigma, mdb = _headline_sigma(self.name, theta, covariance)
        held_out, held_out_se = _held_out(lin, self.base, self.k)
        # the fall of J (m^2, whitened cost x sigma0^2 over the weight sum) the projected candidate explains
        explained_rms_m = lin.sigma0_m * float(np.sqrt(max(theta @ self.S @ theta, 0.0)
                                                       / max(lin.half_weight.sum(), 1e-300)))
        return CandidateTest(self.name, d, statistic, float(stats.chi2.sf(statistic, d)), float(u @ S_inv @ u),
                             theta, covariance, candidate(self.name).magnitude_of(theta), sigma, mdb, self.r2,
                             _absorbing(lin.information, self.base, self.k, self.Xs, S_inv, theta, lin.names),
                             held_out, lin.n_clusters, explained_rms_m, lin.sigma0_m, held_out_se)


def score_each(lin: Linearisation, candidates_of: dict[str, list[str]]) -> dict[str, CandidateTest]:
    """The score test of each name against a base of every parameter but its own candidates' ({name:
    candidates}). The data's rows are made once for all of them (_cluster_variances)."""
    projections = [_Projection.of(lin, name, candidates) for name, candidates in candidates_of.items()]
    testable = [p for p in projections if p.testable]
    variances = _cluster_variances(lin, testable)
    return {p.name: p.test(lin, variances[p.name]) if p.testable else p.untestable(lin) for p in projections}


def score_candidates(lin: Linearisation, names: list[str], candidates: list[str]) -> dict[str, CandidateTest]:
    """The score test of each of names against a base of every parameter but the candidates'."""
    return score_each(lin, dict.fromkeys(names, candidates))


def score_candidate(lin: Linearisation, name: str, candidates: list[str]) -> CandidateTest:
    """The score test of one candidate against a base of every parameter but the candidates'."""
    return score_each(lin, {name: candidates})[name]


def _cluster_variances(lin: Linearisation, projections: list[_Projection]) -> dict[str, np.ndarray]:
    """Cluster-robust variance (d, d) of each candidate's projected score, with the candidate fitted
    (theta): sum over clusters of u_c u_c^T, u_c = -J~_c^T (r_c + J~_c theta), J~ = J_k - J_b Xs the
    candidate's Jacobian projected off the base. At theta the candidate's own signal is out of the
    scores: their spread is the noise's, correlated within clusters, not the effect's. One pass over the
    data's rows for every candidate."""
    scores = {p.name: np.zeros((lin.n_clusters, len(p.k))) for p in projections}
    if not projections:
        return {}
    places = []
    for p in projections:
        position = np.full(len(lin.names), -1)
        position[p.base] = np.arange(len(p.base))
        where_k = np.full(len(lin.names), -1)
        where_k[p.k] = np.arange(len(p.k))
        places.append((position, where_k))
    for cluster, A, r, cols in lin.row_blocks():
        for p, (position, where_k) in zip(projections, places):
            in_base, in_k = position[cols] >= 0, where_k[cols] >= 0
            J = np.zeros((len(r), len(p.k)))
            J[:, where_k[cols[in_k]]] = A[:, in_k]
            J -= A[:, in_base] @ p.Xs[position[cols[in_base]]]
            np.add.at(scores[p.name], cluster, -J * (r + J @ p.theta)[:, None])
    return {name: c.T @ c for name, c in scores.items()}


def _absorbing(L, base, k, Xs, S_inv, theta, names, top: int = 3) -> list:
    """Base parameters most correlated with the candidate (along its estimate) in the joint covariance."""
    direction = theta / np.linalg.norm(theta) if np.linalg.norm(theta) > 0 else np.eye(len(k))[0]
    cross = -(direction @ S_inv) @ Xs.T  # Cov(direction . theta, x_b)
    var_theta = direction @ S_inv @ direction
    var_base = np.diag(_solve(L[np.ix_(base, base)], np.eye(len(base)))) + np.einsum("ij,jk,ik->i", Xs, S_inv, Xs)
    if not len(base):
        return []
    correlation = cross / np.sqrt(np.maximum(var_theta * var_base, 1e-300))
    order = np.argsort(-np.abs(correlation))[:top]
    return [(names[base[j]], float(correlation[j])) for j in order]


def _held_out(lin: Linearisation, base: np.ndarray, k: np.ndarray) -> tuple[tuple[float, float], float]:
    """Held-out J [cm^2] of the base model and of base + candidate: fitted (one linear step) on one
    half's pairs and the priors, evaluated on the other half; both ways, averaged. And the standard
    error [cm^2] of the drop between them across the held-out folds of time blocks: each half's drop is a
    ratio (cost difference over weight summed over its folds), its variance the ratio estimator's over the
    folds (residuals within a time block share surfaces and noise; blocks do not)."""
    if not np.all(lin.half_weight > 0):  # a half of the drive without pairs (a recording of one time block)
        return (np.nan, np.nan), np.inf
    both = np.r_[base, k]
    costs = np.zeros((2, FOLDS))  # whitened cost of each fold after the step fitted on the other half
    for fit in (0, 1):
        L = lin.half_information[fit] + lin.prior_information
        eta = lin.half_vector[fit] + lin.prior_vector
        held = np.arange(1 - fit, FOLDS, 2)
        for m, columns in enumerate((base, both)):
            step = np.zeros(len(lin.names))
            step[columns] = _solve(L[np.ix_(columns, columns)], eta[columns])
            costs[m, held] = (lin.fold_cost[held] - 2 * lin.fold_vector[held] @ step
                              + np.einsum("i,fij,j->f", step, lin.fold_information[held], step))
    to_cm2 = lin.sigma0_m ** 2 * 1e4
    out = [sum(costs[m, h::2].sum() / lin.half_weight[h] for h in (0, 1)) / 2 * to_cm2 for m in (0, 1)]
    drop, variance = costs[0] - costs[1], 0.0
    for h in (0, 1):
        folds = np.flatnonzero((np.arange(FOLDS) % 2 == h) & (lin.fold_weight > 0))
        if len(folds) < 2:
            return (float(out[0]), float(out[1])), np.inf
        weight = lin.fold_weight[folds]
        ratio = drop[folds].sum() / weight.sum()
        with np.errstate(over="ignore"):  # a step the held-in half does not bound: an infinite spread
            variance += (np.sum((drop[folds] - ratio * weight) ** 2) / weight.sum() ** 2
                         * len(folds) / (len(folds) - 1))
    return (float(out[0]), float(out[1])), float(np.sqrt(variance) / 2 * to_cm2)


def separation(lin: Linearisation, a: str, b: str, candidates: list[str]) -> float:
    """Largest canonical correlation of two candidates' signatures once the base is projected off:
    near 1, the data cannot tell them apart."""
    ka, kb = lin.effect_columns[a], lin.effect_columns[b]
    others = np.concatenate([lin.effect_columns[c] for c in candidates])
    base = np.setdiff1d(np.arange(len(lin.names)), others)
    both = np.r_[ka, kb]
    L = lin.information
    S = L[np.ix_(both, both)] - L[np.ix_(both, base)] @ _solve(L[np.ix_(base, base)], L[np.ix_(base, both)])
    na = len(ka)

    def inv_sqrt(M):
        w, V = np.linalg.eigh(M)
        return (V / np.sqrt(np.maximum(w, w.max() * 1e-15))) @ V.T

    cross = inv_sqrt(S[:na, :na]) @ S[:na, na:] @ inv_sqrt(S[na:, na:])
    return float(np.linalg.svd(cross, compute_uv=False).max())
