"""Covariance of the estimate from the pairs' own residuals, clustered by time (a sandwich that trusts no noise model).

The sigmas of shared_returns.py follow from a model of the residuals: each return's range noise, the plane
model's and the trajectory's jitter. Whatever else moves the residuals (surfaces rougher than planes, the pair
choice, a physics the model leaves out, a head that differs from the model) stays out of them, and on such data
the errors exceed those sigmas. The residuals themselves carry it. With A the whitened Jacobian of the pairs
(rows a_k) and r their whitened residuals at the estimate, each time block c of the drive gives a score
g_c = sum_{k in c} a_k r_k; the blocks are taken as independent of one another, the pairs inside a block not:

    Cov(dx) = H^-1 (G/(G-1) sum_c (g_c - g)(g_c - g)^T + P) H^-1,    g the mean score over the G blocks,

with P the priors' information (the nominal values are off by their priors' sigmas), the cluster-robust sandwich
(docs/reference/math.md "Observability"). The scores are centred: at the estimate their sum balances the
priors' pull, which is not noise. A block lasts BLOCK_S, about the time a facade stays in view; fewer than
MIN_BLOCKS blocks leave the sandwich undetermined (None).

A bias common to a whole class of surfaces (the ground's departures from the plane model, say) pushes every time
block the same way: the clusters cannot see it. Where the classes disagree, it shows. With S_k = A_k^T r_k the
score of class k at the estimate (ground, walls, the rest, each split into its near and far pairs:
`surface_classes`), and E_k its covariance
were no class biased (S_k moves with its own noise and with the estimate's step, S_k = S_k0 - H_k H^-1 sum_j S_j0),
each calibration parameter's variance gains the excess of the classes' pushes over what their noise explains,

    sum_k (l_i^T H^-1 S_k)^2 - sum_k l_i^T H^-1 E_k H^-1 l_i,     floored at 0,

(a method-of-moments estimate of a between-class variance, as DerSimonian and Laird's across studies;
docs/reference/math.md "Observability"), l_i the functional that reads parameter i in the axes its sigma is
reported in (a vector's own coordinate; for the extrinsic pose, its tangent turned into the body's axes,
observability.tangent_to_axes). It widens the parameters the classes disagree on, and none where they agree
within their noise. Each reported axis is widened on its own, so that a weak axis's widening does not leak into
a determined one: widened in the tangent's coordinates instead, the extrinsic's translation (in the head's axes,
pitched and turned against the body's) would spread a named lever arm z's 1.2 m into the body's x: 59 cm where
the sandwich itself gives 2 mm (a revisiting city loop). Classes that share one bias do not show it, and a
biased class that holds most of a parameter's information takes the estimate with it: the others then disagree
little.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.sparse as sparse

from graphcal.calibration.observability import FactorisedMarginals, Meat
from graphcal.calibration.shared_returns import Linearised

BLOCK_S = 0.5
MIN_BLOCKS = 20
CLASS_WITHIN_DEG = 25.0  # a pair's world normal this close to the vertical: ground; to the horizontal: a wall


def cluster_robust_covariance(linearised: Linearised, time_s: np.ndarray, surface: np.ndarray | None = None,
                              axes: dict[int, np.ndarray] | None = None) -> FactorisedMarginals:
    """The sandwich above for every key of the graph, with gtsam.Marginals' interface (marginalCovariance(key), in
    each key's tangent space). linearised: the undamped graph at the estimate (shared_returns.Linearised); time_s:
    each pair's time [s] (of p); surface: each pair's surface class (surface_classes), with axes {key: T} the
    calibration's keys whose variances the classes' disagreement widens (none without), T (width, width) the map
    of the key's tangent into the axes its sigmas are reported in (the identity for a vector)."""
    A, r = linearised.A, linearised.r
    block_of = _time_blocks(time_s)
    covariance = linearised.sandwich(ClusteredScores.of(A, r, block_of).meat())
    if surface is None or not axes:
        return covariance
    return covariance.widened(between_classes_variance(linearised, block_of, surface, axes))


def surface_classes(normal_world: np.ndarray, separation_m: np.ndarray) -> np.ndarray:
    """(K,) each pair's class from its world normal (K, 3) and the distance between its p and m [m] (K,): its surface
    (ground, wall, the rest) times two, plus one for the pairs further apart than the median of their surface's.
    A plane model's departures from the surface (a crease between p and m, a curvature) grow with that distance, so
    where they bias the fit the near and the far half of a surface disagree; and each half holds about half of its
    surface's information, where a whole ground class would hold most of the lowest fibres' (module docstring)."""
    vertical = np.abs(np.asarray(normal_world)[:, 2])
    surface = np.where(vertical >= np.cos(np.radians(CLASS_WITHIN_DEG)), 0,
                       np.where(vertical <= np.sin(np.radians(CLASS_WITHIN_DEG)), 1, 2))
    far = np.zeros(len(surface), dtype=int)
    for k in np.unique(surface):
        rows = surface == k
        far[rows] = separation_m[rows] > np.median(separation_m[rows])
    return 2 * surface + far


def between_classes_variance(linearised: Linearised, block_of: np.ndarray, surface: np.ndarray,
                             axes: dict[int, np.ndarray]) -> dict[int, np.ndarray]:
    """{key: the covariance added to its tangent block}: the excess of the surface classes' pushes over their noise
    (module docstring) on each of the key's reported axes (axes[key] = T, tangent -> reported), added along that
    axis alone: T^-1 diag(excess) T^-T. A class spanning fewer than MIN_BLOCKS time blocks joins the last."""
    A, r = linearised.A, linearised.r
    classes = [np.flatnonzero(surface == k) for k in np.unique(surface)]
    small = [c for c in classes if len(np.unique(block_of[c])) < MIN_BLOCKS]
    classes = [c for c in classes if len(np.unique(block_of[c])) >= MIN_BLOCKS]
    if small and classes:
        classes[-1] = np.sort(np.concatenate([classes[-1], *small]))
    keys = list(axes)
    bread = linearised.bread
    columns = [bread.columns_of(key) for key in keys]
    if len(classes) < 2:
        return {key: np.zeros((len(c), len(c))) for key, c in zip(keys, columns)}
    rows = np.concatenate(columns)
    C_R = scipy.linalg.block_diag(*(axes[key] for key in keys)) @ bread.rows(rows)  # rows l_i^T C, C = H^-1
    jacobians = [A[c] for c in classes]
    # each class's clustered meat V_k = Z_k^T Z_k kept as its scores Z_k (time blocks x columns): no n x n per class
    scores = [ClusteredScores.of(A_k, r[c], block_of[c]) for c, A_k in zip(classes, jacobians)]
    pushed, noise = np.zeros(len(rows)), np.zeros(len(rows))
    for c, A_k, Z_k in zip(classes, jacobians, scores):
        D_R = bread.solve((A_k.T @ A_k) @ C_R.T).T  # rows R of C H_k C
        pushed += (C_R @ (A_k.T @ r[c])) ** 2
        # diag of C V_k C - 2 (C H_k C) V_k C + (C H_k C) V (C H_k C), V = sum_j V_j + the priors' information
        noise += np.sum(Z_k.times((C_R - 2 * D_R).T) * Z_k.times(C_R.T), axis=0)
        noise += sum(np.sum(Z_j.times(D_R.T) ** 2, axis=0) for Z_j in scores)
        noise += np.sum((linearised.priors_information @ D_R.T).T * D_R, axis=1)
    excess = np.split(np.maximum(pushed - noise, 0.0), np.cumsum([len(c) for c in columns])[:-1])
    return {key: _along_axes(axes[key], v) for key, v in zip(keys, excess)}


def _along_axes(T: np.ndarray, variance: np.ndarray) -> np.ndarray:
    """T^-1 diag(variance) T^-T: a tangent covariance that adds variance[i] to reported axis i (T: tangent ->
    reported axes) and nothing to the others nor to their covariances."""
    inverse = np.linalg.inv(T)
    return (inverse * variance) @ inverse.T


def _time_blocks(time_s: np.ndarray) -> np.ndarray:
    """Each pair's time block (BLOCK_S), numbered from 0."""
    return np.unique(np.floor(np.asarray(time_s) / BLOCK_S), return_inverse=True)[1].ravel()


@dataclass(frozen=True)
class ClusteredScores:
    """Z (G, columns) with Z^T Z = G/(G-1) sum_c (g_c - g)(g_c - g)^T over the G time blocks the pairs span (module
    docstring), the clustered meat's factor, kept as the blocks' sparse scores g_c (each touches the calibration and
    the controls near its time): Z = f (Z0 - 1 g^T), f = sqrt(G/(G-1)); centred, it would be dense."""

    blocks: sparse.csr_matrix
    factor: float

    @classmethod
    def of(cls, A, r: np.ndarray, block_of: np.ndarray) -> ClusteredScores:
        """A: the pairs' whitened Jacobian, r their whitened residuals, block_of their time blocks."""
        _, block_of = np.unique(block_of, return_inverse=True)
        n_blocks = int(block_of.max()) + 1 if len(r) else 0
        blocks = sparse.csr_matrix((r, (block_of.ravel(), np.arange(len(r)))), shape=(n_blocks, len(r))) @ A
        return cls(sparse.csr_matrix(blocks), float(np.sqrt(n_blocks / max(n_blocks - 1, 1))))

    def times(self, X: np.ndarray) -> np.ndarray:
        """Z @ X for X (columns, k) dense."""
        product = self.blocks @ X
        return self.factor * (product - product.mean(axis=0))

    def meat(self) -> Meat:
        """Z^T Z = f^2 (Z0^T Z0 - G g g^T), kept as its factors."""
        mean = np.asarray(self.blocks.mean(axis=0))
        return Meat(factors=((self.blocks, self.factor ** 2), (mean, -self.factor ** 2 * self.blocks.shape[0])))


def determined(time_s: np.ndarray) -> bool:
    """Whether the pairs span MIN_BLOCKS time blocks or more."""
    return len(np.unique(np.floor(np.asarray(time_s) / BLOCK_S))) >= MIN_BLOCKS
