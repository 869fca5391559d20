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
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sparse

from graphcal.calibration.observability import DenseMarginals
from graphcal.calibration.shared_returns import Linearised

BLOCK_S = 0.5
MIN_BLOCKS = 20


def cluster_robust_covariance(linearised: Linearised, time_s: np.ndarray) -> DenseMarginals:
    """The sandwich above for every key of the graph, with gtsam.Marginals' interface (marginalCovariance(key), in
    each key's tangent space). linearised: the undamped graph at the estimate (shared_returns.Linearised); time_s:
    each pair's time [s] (of p)."""
    A, r = linearised.A, linearised.r
    _, block_of = np.unique(np.floor(np.asarray(time_s) / BLOCK_S), return_inverse=True)
    n_blocks = int(block_of.max()) + 1 if len(time_s) else 0
    scores = (sparse.csr_matrix((r, (block_of, np.arange(len(r)))), shape=(n_blocks, len(r))) @ A).toarray()
    scores -= scores.mean(axis=0)
    return linearised.sandwich(n_blocks / (n_blocks - 1) * scores.T @ scores)


def determined(time_s: np.ndarray) -> bool:
    """Whether the pairs span MIN_BLOCKS time blocks or more."""
    return len(np.unique(np.floor(np.asarray(time_s) / BLOCK_S))) >= MIN_BLOCKS
