"""Data association of eq. 4.4: for each fibre i, the nearest return of each neighbouring fibre
j in [i-N, i+N] (elevation order), with the normal and dimensionality features at p.

Plain NumPy arrays in and out, so that it can run tile by tile on workers while the factor
graph stays on the driver. Points are world coordinates minus a local origin [m].
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import open3d as o3d
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

    def take(self, rows: np.ndarray) -> Correspondences:
        """The pairs at rows (indices or a boolean mask)."""
        return Correspondences(self.index_p[rows], self.index_m[rows], self.normal[rows], self.weight[rows])


def local_features(points_m: np.ndarray, radius_m: float = 0.5, max_nn: int = 20, voxel_m: float = 0.0) -> Features:
    """Normals and dimensionality features at every point, from the covariance of its max_nn
    nearest neighbours within radius_m (open3d, multi-threaded). Degenerate neighbourhoods
    (fewer than 3 points, or a line) get planarity 0.

    voxel_m > 0: the features are computed on the cloud averaged in voxels of that size and each
    point takes those of its nearest voxel. A static sensor needs it: it sees the same spots every
    revolution, so a point's nearest neighbours are itself seen again, a blob of range noise whose
    "normal" is meaningless (measured on the real HDL-32E recording: J 256 cm2 at the nominal
    calibration, 15 cm2 with 0.1 m voxels); voxels coarse enough let the neighbourhood span rings."""
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points_m, dtype=np.float64)))
    if voxel_m > 0:
        sampled = np.asarray(cloud.voxel_down_sample(voxel_m).points)
        nearest = cKDTree(sampled).query(points_m, workers=-1)[1]
        features = local_features(sampled, radius_m, max_nn)
        return Features(*(np.asarray(field)[nearest] for field in (features.normal, features.linearity,
                                                                     features.planarity, features.scattering)))
    cloud.estimate_covariances(o3d.geometry.KDTreeSearchParamHybrid(radius=radius_m, max_nn=max_nn))
    eigenvalues, eigenvectors = np.linalg.eigh(np.asarray(cloud.covariances))  # ascending
    s = np.sqrt(np.clip(eigenvalues, 0.0, None))[:, ::-1]  # s1 >= s2 >= s3
    s1 = np.where(s[:, 0] > 0, s[:, 0], 1.0)
    valid = s[:, 1] > 0
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
              gate_m: float, min_planarity: float = 0.3, min_normal_cos: float = 0.0,
              max_plane_distance_m: float = np.inf, max_pairs_per_fibre_pair: int | None = None, rng: np.random.Generator | None = None,
              candidates: np.ndarray | None = None) -> Correspondences:
    """Nearest return m of fibre j for every candidate return p of fibre i (j a neighbour of i).

    A pair is kept when |p - m| < gate_m, both p and m are planar enough (planarity >=
    min_planarity) and lie on the same surface (|n_p . n_m| >= min_normal_cos, and m within
    max_plane_distance_m of the plane at p): pairs across an edge, or between two parallel faces
    (a car's cabin side above its body side), would pull the offsets even at the true calibration. Weight = planarity at p (eq. 4.4
    w_ijk). features describe every point; candidates are the rows that may be p (all if None).
    max_pairs_per_fibre_pair subsamples each (i, j) pair's correspondences at random (rng)."""
    candidates = np.arange(len(points_m)) if candidates is None else np.asarray(candidates)
    rng = rng or np.random.default_rng(0)
    order = np.argsort(fibre, kind="stable")
    bounds = np.searchsorted(fibre[order], np.unique(fibre), side="left").tolist() + [len(order)]
    by_fibre = {int(fibre[order[start]]): order[start:stop] for start, stop in zip(bounds[:-1], bounds[1:])}
    trees = {f: cKDTree(points_m[rows], balanced_tree=False, compact_nodes=False) for f, rows in by_fibre.items()}
    planar = features.planarity >= min_planarity
    planar_candidates = candidates[planar[candidates]]
    candidate_fibre = fibre[planar_candidates]
    p_of = {i: planar_candidates[candidate_fibre == i] for i in by_fibre}
    jobs = [(i, j) for i in by_fibre for j in neighbours.get(i, []) if j in trees and len(p_of[i])]
    streams = rng.spawn(len(jobs))  # one random stream per fibre pair: the same draws in any thread order

    def pairs_of(job: tuple[int, int], stream: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        i, j = job
        return _pairs_with(p_of[i], points_m, features, planar, by_fibre[j], trees[j], gate_m, min_normal_cos,
                           max_plane_distance_m, max_pairs_per_fibre_pair, stream)

    # the KD-tree queries and NumPy release the GIL: fibre pairs side by side on the cores
    with ThreadPoolExecutor(os.cpu_count() or 1) as pool:
        parts = list(pool.map(pairs_of, jobs, streams))
    if not parts:
        empty = np.zeros(0, dtype=np.int64)
        return Correspondences(empty, empty, np.zeros((0, 3)), np.zeros(0))
    index_p = np.concatenate([p for p, _ in parts])
    index_m = np.concatenate([m for _, m in parts])
    return Correspondences(index_p, index_m, features.normal[index_p], features.planarity[index_p])


def _pairs_with(p_rows: np.ndarray, points_m: np.ndarray, features: Features, planar: np.ndarray,
                j_rows: np.ndarray, tree: cKDTree, gate_m: float, min_normal_cos: float, max_plane_distance_m: float,
                most: int | None, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(p, m) rows: the candidates p_rows paired with their nearest return of fibre j (rows j_rows, in
    tree), as associate keeps them; at most `most`, a uniform random subset of those kept: the
    candidates are taken in a random order and only as many are searched as it takes to keep `most`."""
    if most is not None:
        p_rows = p_rows[rng.permutation(len(p_rows))]
    chunk = len(p_rows) if most is None else 2 * most
    kept_p, kept_m, count = [], [], 0
    for start in range(0, len(p_rows), chunk):
        p = p_rows[start:start + chunk]
        distance, nearest = tree.query(points_m[p], k=1, distance_upper_bound=gate_m)
        found = np.isfinite(distance)
        p, m = p[found], j_rows[nearest[found]]
        normal = features.normal[p]
        same_surface = (planar[m] & (np.abs(np.einsum("ni,ni->n", normal, features.normal[m])) >= min_normal_cos)
                        & (np.abs(np.einsum("ni,ni->n", normal, points_m[p] - points_m[m])) <= max_plane_distance_m))
        kept_p.append(p[same_surface])
        kept_m.append(m[same_surface])
        count += int(same_surface.sum())
        if most is not None and count >= most:
            break
    p, m = np.concatenate(kept_p)[:most], np.concatenate(kept_m)[:most]
    order = np.argsort(p, kind="stable")
    return p[order], m[order]
