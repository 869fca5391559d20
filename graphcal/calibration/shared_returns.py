"""Covariance of the estimate when pairs share returns (a noisy head).

gtsam.Marginals give H^-1, H the graph's information: the covariance of the estimate if every
pair's residual carried its own independent noise. It does not: a return's range noise moves it
along its line of sight u by eps (sigma the range noise) in every pair it serves in, as p or as m.
To first order the estimate moves by dx = -H^-1 A^T dr, with A the whitened Jacobian (rows: pairs)
and dr_k = s_k (n_k.u_p eps_p - n_k.u_m eps_m + eta_k), s_k = sqrt(w_k) / sigma_k the pair's
whitening, eta_k the pair's own independent part (the INCIDENCE_FLOOR and plane-model terms of its sigma_k). So

    Cov(dx) = H^-1 (sum_r g_r g_r^T + sum_k v_k a_k a_k^T + P) H^-1,
    g_r = sigma sum_{pairs k using return r} s_k (+-n_k.u_r) a_k,   v_k = max(w_k - s_k^2 sigma^2 ((n.u_p)^2 + (n.u_m)^2), 0)

with P the priors' information (the nominal values are off by their priors' sigmas: the estimate
inherits that error where the data see little), a sandwich (docs/reference/math.md "Observability"). With no return
shared and unit weights it is H^-1.

Returns fired close in time share their pose too. The error smoothing leaves in the recorded poses
(ReturnData.smoothing_error: sigma_t [m] and sigma_a [rad] per axis, one draw per interval tau) moves every
return fired in a window of tau alike: by dX + e x l, l the return minus the body's position. A window w adds

    sum_w sum_c sigma_c^2 h_wc h_wc^T,   h_wc = sum_{pairs k} s_k (b_kc [p in w] - b'_kc [m in w]) a_k,

b_k = (n_k, l_p x n_k) over the components c (translation, rotation), b'_k the same at m: a common error of a
few tens of milliseconds of poses moves the thousands of pairs that saw them together, which no pair's own
sigma can say.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np
import scipy.sparse as sparse

from factors.point_to_plane import Block, residuals
from graphcal.calibration.association import Correspondences
from graphcal.calibration.observability import (
    FactorisedMarginals,
    Meat,
    first_columns,
    information_of,
    tangent_widths,
)
from graphcal.calibration.returns import Estimate, ReturnData, rays_at, world_at

RETURNS_PER_CHUNK = 200_000  # rows of g computed at once (memory: about 38 nonzeros each)


@dataclass(frozen=True)
class Linearised:
    """The undamped graph at the estimate as the sandwich covariances need it: its marginals (the bread H^-1, H
    including the priors, factorised once) and the whitened Jacobian A of every pair (pairs x the graph's columns,
    sparse), the pairs' whitened residuals r and whitenings s = sqrt(w) / sigma, and P the priors'
    information (sparse). Made once, shared by this module's sandwich and cluster_robust.py's."""

    bread: FactorisedMarginals
    A: sparse.csr_matrix
    r: np.ndarray
    scale: np.ndarray
    priors_information: sparse.csr_matrix

    @classmethod
    def of(cls, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, blocks: list[tuple[np.ndarray, Block]],
           n_pairs: int, robust: bool = False) -> Linearised:
        """blocks: the graph's point-to-plane blocks with their rows among the n_pairs pairs, its first factors
        (Problem.graph); the factors after them are the priors'. H = A^T A + P, or, where a robust loss
        reweights the blocks (robust), their own information at values + P."""
        widths = tangent_widths(values)
        A, r, scale = whitened_jacobian(blocks, values, first_columns(widths), n_pairs, sum(widths.values()))
        priors = information_of(graph, values, widths, range(len(blocks), graph.size()))
        information = (information_of(graph, values, widths, range(len(blocks))) if robust else A.T @ A) + priors
        return cls(FactorisedMarginals.of(information, widths), A, r, scale, priors)

    def sandwich(self, meat_of_pairs: Meat) -> FactorisedMarginals:
        """H^-1 (meat_of_pairs + P) H^-1, P the priors' information: the nominal values are off by their
        priors' sigmas, an error the estimate inherits where the data are silent (a weak direction held at nominal)."""
        return self.bread.sandwich(meat_of_pairs + Meat(self.priors_information))


def shared_returns_covariance(linearised: Linearised, pairs: Correspondences, data: ReturnData, estimate: Estimate,
                              range_noise_m: float) -> FactorisedMarginals:
    """The sandwich covariance above for every key of the graph, with gtsam.Marginals' interface
    (marginalCovariance(key), in each key's tangent space). range_noise_m: sigma, the range noise of one return."""
    A, scale = linearised.A, linearised.scale
    along_p = np.einsum("ni,ni->n", pairs.normal, rays_at(data, estimate, pairs.index_p))
    along_m = np.einsum("ni,ni->n", pairs.normal, rays_at(data, estimate, pairs.index_m))
    own = np.maximum(pairs.weight - (scale * range_noise_m) ** 2 * (along_p ** 2 + along_m ** 2), 0.0)
    meat = A.T @ sparse.diags(own) @ A
    # S (returns x pairs): return r's coefficient in each pair's residual, sigma s_k (+-n.u)
    n_pairs = len(pairs)
    S = sparse.csr_matrix((np.r_[scale * range_noise_m * along_p, -scale * range_noise_m * along_m],
                           (np.r_[pairs.index_p, pairs.index_m], np.r_[np.arange(n_pairs), np.arange(n_pairs)])),
                          shape=(len(data.time_s), n_pairs))
    for first in range(0, S.shape[0], RETURNS_PER_CHUNK):
        G = S[first:first + RETURNS_PER_CHUNK] @ A  # rows g_r
        meat += G.T @ G
    return linearised.sandwich(Meat(meat + shared_poses_meat(linearised, pairs, data, estimate)))


def shared_poses_meat(linearised: Linearised, pairs: Correspondences, data: ReturnData,
                      estimate: Estimate) -> sparse.csr_matrix:
    """sum_w sum_c sigma_c^2 h_wc h_wc^T (module docstring): what the error left in the smoothed poses
    (data.smoothing_error) adds to the information's meat, in the graph's columns, sparse (empty when none is
    left)."""
    noise, A = data.smoothing_error, linearised.A
    if not noise.interval_s > 0 or not len(pairs):
        return sparse.csr_matrix((A.shape[1], A.shape[1]))
    n_pairs = len(pairs)
    returns = np.r_[pairs.index_p, pairs.index_m]  # each pair's p, then each pair's m
    normals = np.tile(pairs.normal, (2, 1))
    arms = np.cross(world_at(data, estimate, False, returns) - data.X_nav[returns], normals)
    window = np.floor((data.time_s[returns] - data.time_s.min()) / noise.interval_s).astype(np.int64)
    sign = np.r_[np.ones(n_pairs), -np.ones(n_pairs)] * np.tile(linearised.scale, 2)
    coefficients = np.column_stack([normals * noise.position_m, arms * noise.attitude_rad])
    rows = window[:, None] * 6 + np.arange(6)  # (window, component)
    columns = np.broadcast_to(np.tile(np.arange(n_pairs), 2)[:, None], rows.shape)
    H = sparse.csr_matrix(((sign[:, None] * coefficients).ravel(), (rows.ravel(), columns.ravel())),
                          shape=(6 * (int(window.max()) + 1), n_pairs)) @ A
    return sparse.csr_matrix(H.T @ H)


def whitened_jacobian(blocks: list[tuple[np.ndarray, Block]], values: gtsam.Values, column: dict[int, int],
                      n_pairs: int, width: int) -> tuple[sparse.csr_matrix, np.ndarray, np.ndarray]:
    """The whitened Jacobian of every pair's residual (pairs x the graph's columns, sparse), the whitened
    residuals r_k (0 for a pair no estimated key moves) and each pair's whitening s_k = sqrt(w_k) / sigma_k."""
    rows, cols, vals = [], [], []
    scale, whitened = np.zeros(n_pairs), np.zeros(n_pairs)
    for pair_rows, block in blocks:
        whitened[pair_rows], J = residuals(block, values)
        to_global = np.concatenate([column[key] + np.arange(block.widths[key]) for key in block.widths])
        r, c = np.nonzero(J)
        rows.append(pair_rows[r])
        cols.append(to_global[c])
        vals.append(J[r, c])
        scale[pair_rows] = np.sqrt(block.weight) / block.sigma0_m
    if not blocks:  # no pair moves with an estimated key
        return sparse.csr_matrix((n_pairs, width)), whitened, scale
    A = sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n_pairs, width))
    return A, whitened, scale
