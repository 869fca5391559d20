"""Data association of eq. 4.4: for each fibre i, the nearest return of each neighbouring fibre
j in [i-N, i+N] (elevation order), with the normal and dimensionality features at p.

Plain NumPy arrays in and out, so that it can run tile by tile on workers while the factor
graph stays on the driver. Points are world coordinates minus a local origin [m].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree


@dataclass(frozen=True)
class Features:
    """Per-point local shape from the k nearest neighbours: unit normal (N,3) and the
    dimensionality features of the sqrt-eigenvalues s1 >= s2 >= s3 of the covariance:
    linearity (s1-s2)/s1, planarity (s2-s3)/s1, scattering s3/s1 (each in [0, 1])."""

    normal: np.ndarray
    linearity: np.ndarray
    planarity: np.ndarray
    scattering: np.ndarray


@dataclass(frozen=True)
class Correspondences:
    """Pairs (p, m) as row indices into the cloud, with the normal at p and a weight in [0, 1]."""

    index_p: np.ndarray
    index_m: np.ndarray
    normal: np.ndarray
    weight: np.ndarray

    def __len__(self) -> int:
        return len(self.index_p)


def local_features(points_m: np.ndarray, radius_m: float = 0.5, max_nn: int = 20,
                   query_index: np.ndarray | None = None) -> Features:
    """Normals and dimensionality features at points[query_index] (all points if None), from
    their max_nn nearest neighbours within radius_m. Fewer than 3 neighbours: planarity 0."""
    points_m = np.asarray(points_m, dtype=np.float64)
    queries = points_m if query_index is None else points_m[query_index]
    distance, nearest = cKDTree(points_m).query(queries, k=max_nn, distance_upper_bound=radius_m, workers=-1)
    found = np.isfinite(distance)
    count = found.sum(axis=1)
    neighbourhood = points_m[np.where(found, nearest, 0)]  # (M, k, 3), padded rows masked below
    mask = found[:, :, None]
    mean = (neighbourhood * mask).sum(axis=1) / np.maximum(count, 1)[:, None]
    centred = (neighbourhood - mean[:, None, :]) * mask
    covariance = np.einsum("mki,mkj->mij", centred, centred) / np.maximum(count, 1)[:, None, None]
    eigenvalues, eigenvectors = np.linalg.eigh(covariance)  # ascending
    s = np.sqrt(np.clip(eigenvalues, 0.0, None))[:, ::-1]  # s1 >= s2 >= s3
    s1 = np.where(s[:, 0] > 0, s[:, 0], 1.0)
    valid = (count >= 3) & (s[:, 1] > 0)
    return Features(normal=eigenvectors[:, :, 0],
                    linearity=np.where(valid, (s[:, 0] - s[:, 1]) / s1, 0.0),
                    planarity=np.where(valid, (s[:, 1] - s[:, 2]) / s1, 0.0),
                    scattering=np.where(valid, s[:, 2] / s1, 0.0))


def neighbour_fibres(elevation_deg: np.ndarray, n_steps: int) -> dict[int, list[int]]:
    """For each fibre, the fibres within n_steps of it in elevation order (itself excluded)."""
    order = np.argsort(elevation_deg, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return {int(i): [int(order[r]) for r in range(max(rank[i] - n_steps, 0), min(rank[i] + n_steps + 1, len(order)))
                     if order[r] != i] for i in range(len(order))}


def associate(points_m: np.ndarray, fibre: np.ndarray, features: Features, neighbours: dict[int, list[int]],
              gate_m: float, min_planarity: float = 0.3, max_pairs_per_fibre_pair: int | None = None,
              rng: np.random.Generator | None = None, candidates: np.ndarray | None = None) -> Correspondences:
    """Nearest return m of fibre j for every candidate return p of fibre i (j a neighbour of i),
    kept when |p - m| < gate_m and p is planar enough; weight = planarity at p (eq. 4.4 w_ijk).

    candidates: the rows of the cloud that `features` describe, in order (all rows if None).
    max_pairs_per_fibre_pair subsamples each (i, j) pair's correspondences at random (rng)."""
    candidates = np.arange(len(points_m)) if candidates is None else np.asarray(candidates)
    rng = rng or np.random.default_rng(0)
    by_fibre = {int(f): np.flatnonzero(fibre == f) for f in np.unique(fibre)}
    trees = {f: cKDTree(points_m[rows]) for f, rows in by_fibre.items() if len(rows)}
    planar = features.planarity >= min_planarity
    parts = []
    for i in by_fibre:
        slots = np.flatnonzero((fibre[candidates] == i) & planar)  # positions in candidates
        if not len(slots):
            continue
        for j in neighbours.get(i, []):
            if j not in trees:
                continue
            distance, nearest = trees[j].query(points_m[candidates[slots]], k=1, distance_upper_bound=gate_m,
                                               workers=-1)
            found = np.isfinite(distance)
            slot, m = slots[found], by_fibre[j][nearest[found]]
            if max_pairs_per_fibre_pair is not None and len(slot) > max_pairs_per_fibre_pair:
                keep = np.sort(rng.choice(len(slot), max_pairs_per_fibre_pair, replace=False))
                slot, m = slot[keep], m[keep]
            parts.append((slot, m))
    if not parts:
        empty = np.zeros(0, dtype=np.int64)
        return Correspondences(empty, empty, np.zeros((0, 3)), np.zeros(0))
    slot = np.concatenate([s for s, _ in parts])
    index_m = np.concatenate([m for _, m in parts])
    return Correspondences(candidates[slot], index_m, features.normal[slot], features.planarity[slot])
