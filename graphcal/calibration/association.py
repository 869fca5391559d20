"""Data association of eq. 4.4: for each fibre i, the nearest return of each neighbouring fibre
j in [i-N, i+N] (elevation order), with the normal and dimensionality features at p.

Plain NumPy arrays in and out, so that it can run tile by tile on workers while the factor
graph stays on the driver. Points are world coordinates minus a local origin [m].
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, fields, replace
from functools import cached_property

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from graphcal.calibration.config import PhaseGates
from graphcal.common.cluster import usable_cores

LEAST_BENT_CANDIDATES = 6  # voxel means nearest a mean among which least_bent chooses the plane it takes


def rows_of(table, rows: np.ndarray):
    """A dataclass of per-row arrays (Features, Sight) cut to rows: every field at those rows."""
    return type(table)(*(getattr(table, f.name)[rows] for f in fields(table)))


@dataclass(frozen=True)
class Features:
    """Per-point local shape from the k nearest neighbours: unit normal (N,3) and, of the sqrt-eigenvalues
    s1 >= s2 >= s3 of the covariance, the planarity (s2-s3)/s1 (in [0, 1]; the weight of eq. 4.4) and s3 itself,
    out_of_plane_m [m]: the RMS distance of the neighbourhood from its best plane."""

    normal: np.ndarray
    planarity: np.ndarray
    out_of_plane_m: np.ndarray

    def take(self, rows: np.ndarray) -> Features:
        """The features of the points at rows (indices or a boolean mask)."""
        return rows_of(self, rows)


@dataclass(frozen=True)
class Correspondences:
    """Pairs (p, m) as row indices into the cloud, with the normal at p and a weight in [0, 1]; with a
    Sight, the shift [m] along each return's line of sight from it to its stand-in (shift_p_m,
    shift_m_m; None without); out_of_plane_m [m]: the out-of-plane scatter of p's neighbourhood
    (Features.out_of_plane_m), how far the surface around the pair departs from the plane at p
    (None: not known)."""

    index_p: np.ndarray
    index_m: np.ndarray
    normal: np.ndarray
    weight: np.ndarray
    shift_p_m: np.ndarray | None = None
    shift_m_m: np.ndarray | None = None
    out_of_plane_m: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.index_p)

    def rows(self) -> np.ndarray:
        """The returns the pairs use (as p or m), sorted, each once."""
        return np.union1d(self.index_p, self.index_m)

    def take(self, rows: np.ndarray) -> Correspondences:
        """The pairs at rows (indices or a boolean mask)."""
        shifts = (None, None) if self.shift_p_m is None else (self.shift_p_m[rows], self.shift_m_m[rows])
        scatter = None if self.out_of_plane_m is None else self.out_of_plane_m[rows]
        return Correspondences(self.index_p[rows], self.index_m[rows], self.normal[rows], self.weight[rows], *shifts,
                               scatter)


@dataclass(frozen=True)
class Sight:
    """Per return: its unit line of sight rays (N,3) in the points' axes, and the shift_m (N,) [m] along that
    line from the return to its stand-in, the point of the line at the range the PROXY_FIRINGS returns its fibre
    fired before it and after it give at its azimuth (its own range left out; itself at an edge or a gap,
    stand_in_shifts): the stand-in of its range is range + shift (stand_ins). Range noise moves a return
    along its line of sight, so its stand-in does not depend on its own noise."""

    rays: np.ndarray
    shift_m: np.ndarray

    def stand_ins(self, points_m: np.ndarray) -> np.ndarray:
        """The stand-ins (N,3) [m] of the returns at points_m (N,3) [m]: each moved by its shift along its ray
        (not kept: three columns of every return that a tile's job would carry)."""
        return points_m + self.shift_m[:, None] * self.rays

    def take(self, rows: np.ndarray) -> Sight:
        """The lines of sight of the returns at rows (indices or a boolean mask)."""
        return rows_of(self, rows)


def stand_in_shifts(fibre: np.ndarray, range_m: np.ndarray, azimuth_rad: np.ndarray) -> np.ndarray:
    """Sight.shift_m (N,) [m] of returns from their fibres, measured ranges [m] and encoder azimuths [rad] (rows of a
    fibre in firing order): raw data only, so the same at every estimate."""
    shift, found = np.zeros(len(range_m)), np.zeros(len(range_m), bool)
    by_fibre = rows_by_fibre(fibre).values()
    for k in range(PROXY_FIRINGS, 0, -1):  # the most neighbours first; fewer where they reach past an edge
        for rows in by_fibre:
            centre = np.flatnonzero(~found[rows[k:len(rows) - k]]) + k  # positions in rows still without one
            if len(centre):
                inner = rows[centre]
                around = rows[centre[:, None] + np.r_[np.arange(-k, 0), np.arange(1, k + 1)]]
                shift[inner], found[inner] = _shift_to_neighbours(range_m[inner], azimuth_rad[inner],
                                                                  range_m[around], azimuth_rad[around])
    return shift


def _shift_to_neighbours(range_m: np.ndarray, azimuth_rad: np.ndarray, around_range_m: np.ndarray,
                         around_azimuth_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Shift [m] from each return's range (N,) to its stand-in range: its neighbours' ranges (N, 2k: k fired before
    it, then k after) against their encoder azimuths, taken at its own azimuth through the curve a plane gives a
    fibre's cone of rays, 1/range = a + b sin x + c (1 - cos x) with x the azimuth offset (the plane n.X = d:
    1/range = n.ray(azimuth) / d), least squares; the line a + b sin x when k = 1. Exact on any plane whatever the
    head's tilt (a level head's ground ring at constant range; a tilted head's, whose range curves as the head turns
    and which a line through neighbours degrees apart misses by about a millimetre, with one sign along the ring;
    a wall), at the neighbours' spacing whatever it is (a subsample's neighbours lie unevenly on either side). Not
    found (shift 0: the return stands for itself) where its azimuth is not between its neighbours', where a
    neighbour lies further than PROXY_REACH_M from the curve (an edge, a gap) or the shift itself is further."""
    k = around_range_m.shape[1] // 2
    turn = np.exp(1j * (around_azimuth_rad - azimuth_rad[:, None]))  # cos x + i sin x
    sine, versine = turn.imag, 1.0 - turn.real
    sine_reach, versine_reach = np.abs(sine).max(axis=1), versine.max(axis=1)
    between = (sine[:, k - 1] * sine[:, k] < 0) & (versine_reach > 0)  # either way the head turns
    # the basis scaled to [-1, 1]: well-conditioned normal equations at any spacing
    basis = [np.ones_like(sine), sine / np.where(between, sine_reach, 1.0)[:, None],
             versine / np.where(between, versine_reach, 1.0)[:, None]][:min(3, 2 * k)]
    inverse_range = 1.0 / np.maximum(around_range_m, 1e-6)
    normal = [[(f * g).sum(axis=1) for g in basis] for f in basis]
    right = [(f * inverse_range).sum(axis=1) for f in basis]
    determinant = _determinant(normal)
    solvable = between & (np.abs(determinant) > 1e-9)
    determinant = np.where(solvable, determinant, 1.0)
    coefficients = [_determinant([row[:j] + [r] + row[j + 1:] for row, r in zip(normal, right)]) / determinant
                    for j in range(len(basis))]  # Cramer's rule, row by row at once
    solvable &= coefficients[0] > 0
    fitted = sum(c[:, None] * f for c, f in zip(coefficients, basis))  # 1/range at the neighbours
    off_curve = np.abs(around_range_m - 1.0 / np.where(fitted > 0, fitted, np.inf)).max(axis=1)
    shift = 1.0 / np.where(solvable, coefficients[0], 1.0) - range_m
    found = solvable & (off_curve <= PROXY_REACH_M) & (np.abs(shift) <= PROXY_REACH_M)
    return np.where(found, shift, 0.0), found


def _determinant(matrix: list[list[np.ndarray]]) -> np.ndarray:
    """The determinants (N,) of N 2x2 or 3x3 matrices given entry by entry (matrix[i][j]: (N,))."""
    if len(matrix) == 2:
        return matrix[0][0] * matrix[1][1] - matrix[0][1] * matrix[1][0]
    (a, b, c), (d, e, f), (g, h, i) = matrix
    return a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)


def rows_by_fibre(fibre: np.ndarray) -> dict[int, np.ndarray]:
    """Each fibre's rows, in row order."""
    order = np.argsort(fibre, kind="stable")
    bounds = np.searchsorted(fibre[order], np.unique(fibre), side="left").tolist() + [len(order)]
    return {int(fibre[order[start]]): order[start:stop] for start, stop in zip(bounds[:-1], bounds[1:])}


def local_features(points_m: np.ndarray, radius_m: float = 0.5, max_nn: int = 20, voxel_m: float = 0.0,
                   voxel_corner_m: np.ndarray | None = None) -> Features:
    """Normals and dimensionality features at every point, from the covariance of its max_nn
    nearest neighbours within radius_m (open3d, multi-threaded). Degenerate neighbourhoods
    (fewer than 3 points, or a line) get planarity 0.

    voxel_m > 0: the features are computed on the cloud averaged in voxels of that size (voxel_means, on a
    grid with its corner at voxel_corner_m) and each point takes those of the voxel mean nearest it, with the normal
    of the plane least_bent chooses for that mean (not bent across a crease); the planarity and the out-of-plane
    scatter stay the mean's own neighbourhood's, how far the surface there departs from one plane, which a pair's
    sigma counts (taking its own voxel's instead, the static halves check passed the real static recording with one half's
    ground lowered by up to 15 cm: held-out J fell by a fifth where it rises). A static sensor needs it: it sees
    the same spots every revolution, so a point's nearest neighbours are itself seen again, a blob of range noise
    whose "normal" is meaningless (measured on the real HDL-32E recording: J 256 cm2 at the nominal calibration,
    15 cm2 with 0.1 m voxels); voxels coarse enough let the neighbourhood span rings."""
    if voxel_m > 0:
        means_m = voxel_means(points_m, voxel_m, voxel_corner_m)
        tree = cKDTree(means_m)
        nearest = tree.query(points_m, workers=-1)[1]
        own = local_features(means_m, radius_m, max_nn)
        return replace(own, normal=own.normal[least_bent(tree, own, radius_m)]).take(nearest)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points_m, dtype=np.float64)))
    search = o3d.geometry.KDTreeSearchParamHybrid(radius=radius_m, max_nn=max_nn)
    cloud.estimate_covariances(search)
    cloud.estimate_normals(search)  # from the covariances just computed (no second search): their least axis
    normal, covariance = np.asarray(cloud.normals), np.asarray(cloud.covariances)
    s = np.sqrt(np.clip(_eigenvalues_about(covariance, normal), 0.0, None))  # s1 >= s2 >= s3
    s1 = np.where(s[:, 0] > 0, s[:, 0], 1.0)
    valid = s[:, 1] > 0
    return Features(normal=normal, planarity=np.where(valid, (s[:, 1] - s[:, 2]) / s1, 0.0), out_of_plane_m=s[:, 2])


def least_bent(tree: cKDTree, features: Features, radius_m: float, candidates: int = LEAST_BENT_CANDIDATES) -> np.ndarray:
    """(V,) for each voxel mean (tree: a KD-tree of the means [m]) the mean, among its `candidates` nearest within
    radius_m (itself included), whose neighbourhood's plane (features: the means' own) fits it best: the least
    s3^2 + d^2, s3 that neighbourhood's out-of-plane scatter and d this mean's distance from its plane. Within a
    neighbourhood's reach of a crease (a kerb, a ditch's edge) a mean's own neighbourhood straddles it, its normal
    bent towards the other face; one further in on the mean's own face is not, and the mean lies on its plane.
    A pair's residual carries its normal's error times the pair's separation, of one sign along a crease
    (docs/reference/math.md "Features and their refresh")."""
    means_m, scatter = tree.data, features.out_of_plane_m
    itself = np.arange(len(means_m))
    _, nearest = tree.query(means_m, k=candidates, distance_upper_bound=radius_m, workers=-1)
    nearest = np.where(nearest < len(means_m), nearest, itself[:, None])  # itself: always found
    plane_offset_m = np.einsum("ni,ni->n", features.normal, means_m)
    off_plane = np.einsum("nki,ni->nk", features.normal[nearest], means_m) - plane_offset_m[nearest]
    misfit = np.where(features.planarity[nearest] > 0, scatter[nearest] ** 2 + off_plane ** 2, np.inf)
    chosen = nearest[itself, np.argmin(misfit, axis=1)]
    return np.where(np.isfinite(misfit).any(axis=1), chosen, itself)


def voxel_means(points_m: np.ndarray, voxel_m: float, corner_m: np.ndarray | None = None) -> np.ndarray:
    """The mean (V,3) [m] of the points in each occupied voxel: cubes of voxel_m [m] on a grid with a corner at
    corner_m [m] (None: voxel_corner's, the grid of open3d's voxel_down_sample, whose means these are; a tile's halo
    given the whole cloud's corner averages its voxels as the whole cloud does), by one sort of the voxels' packed
    indices: 0.4 s for 3.9 M returns, where voxel_down_sample took 2.2-3.0 s. Where the grid lies matters: with its
    corner at the frame's origin (and each return taking its own voxel's features) the real static recording's
    halves check failed where it passes."""
    points_m = np.asarray(points_m, dtype=np.float64)
    corner_m = voxel_corner(points_m, voxel_m) if corner_m is None else corner_m
    cell = np.floor((points_m - corner_m) / voxel_m).astype(np.int64)
    span = cell.max(axis=0, initial=0) + 1
    _, voxel, count = np.unique((cell[:, 0] * span[1] + cell[:, 1]) * span[2] + cell[:, 2], return_inverse=True,
                                return_counts=True)
    voxel = voxel.ravel()
    return np.column_stack([np.bincount(voxel, weights=points_m[:, k], minlength=len(count)) / count
                            for k in range(3)])


def voxel_corner(points_m: np.ndarray, voxel_m: float) -> np.ndarray:
    """(3,) [m] the corner of open3d's voxel grid for these points: half a voxel below their least coordinates."""
    return np.asarray(points_m).min(axis=0, initial=np.inf) - 0.5 * voxel_m


def _eigenvalues_about(covariance: np.ndarray, least_axis: np.ndarray) -> np.ndarray:
    """The eigenvalues (N, 3), largest first, of symmetric 3x3 matrices (N,3,3) whose least eigenvector is known
    (N,3): that one is the matrix's quadratic form along it, and the other two the roots of the characteristic
    polynomial left (their sum the trace less it, their product the principal minors' sum less it times that
    sum). A batched eigen-decomposition of every return's covariance costs four times the whole of this."""
    c = covariance
    least = np.einsum("ni,nij,nj->n", least_axis, c, least_axis)
    total = c[:, 0, 0] + c[:, 1, 1] + c[:, 2, 2] - least
    minors = (c[:, 0, 0] * c[:, 1, 1] - c[:, 0, 1] ** 2 + c[:, 0, 0] * c[:, 2, 2] - c[:, 0, 2] ** 2
              + c[:, 1, 1] * c[:, 2, 2] - c[:, 1, 2] ** 2)
    half_gap = 0.5 * np.sqrt(np.clip(total ** 2 - 4.0 * (minors - least * total), 0.0, None))
    return np.column_stack([0.5 * total + half_gap, 0.5 * total - half_gap, least])


def neighbour_fibres(elevation_deg: np.ndarray, n_steps: int) -> dict[int, list[int]]:
    """For each fibre, the fibres within n_steps of it in elevation order (itself excluded)."""
    order = np.argsort(elevation_deg, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return {int(i): [int(order[r]) for r in range(max(rank[i] - n_steps, 0), min(rank[i] + n_steps + 1, len(order)))
                     if order[r] != i] for i in range(len(order))}


LINE_CANDIDATES = 16  # stand-ins of fibre j nearest p's among which m is the one whose line of sight passes nearest it
# the stand-ins among which the line of sight chooses m lie within this of p's (the fine gate; none does: the nearest
# one): further, in a coarse gate on a sparse subsample, the line of sight alone prefers a surface seen behind p
LINE_REACH_M = 0.3
PROXY_FIRINGS = 2  # firings on each side of a return whose ranges give its stand-in (then one, past an edge)
PROXY_REACH_M = 0.2  # a return whose neighbours' ranges lie further than this from their curve stands for itself


@dataclass(frozen=True)
class PairCloud:
    """What an association pairs: the points [m, world frame] (N,3), each one's fibre (N,), their features,
    and the lines of sight with stand-ins (returns.sight_at; None: plain nearest returns)."""

    points_m: np.ndarray
    fibre: np.ndarray
    features: Features
    sight: Sight | None = None

    @cached_property
    def stand_ins_m(self) -> np.ndarray:
        """What the association searches (N,3) [m]: the stand-ins (Sight.stand_ins), the points without a sight."""
        return self.points_m if self.sight is None else self.sight.stand_ins(self.points_m)


@dataclass(frozen=True)
class PairGates:
    """What a pair must pass (see associate): within gate_m [m], p and m at least min_planarity planar,
    |n_p . n_m| >= min_normal_cos, m within max_plane_distance_m [m] of the plane at p; and the cap of pairs
    per fibre pair (most; None: no cap)."""

    gate_m: float
    min_planarity: float = 0.3
    min_normal_cos: float = 0.0
    max_plane_distance_m: float = np.inf
    most: int | None = None

    @classmethod
    def of(cls, phase: PhaseGates, gate_m: float, capped: bool = True) -> PairGates:
        """A phase's gates at a gate of gate_m, capped at the phase's pairs per fibre pair (or not)."""
        return cls(gate_m, phase.min_planarity, float(np.cos(np.radians(phase.max_normal_angle_deg))),
                   phase.max_plane_distance_m, phase.pairs_per_fibre_pair if capped else None)


def associate(cloud: PairCloud, neighbours: dict[int, list[int]], gates: PairGates,
              rng: np.random.Generator | None = None, candidates: np.ndarray | None = None) -> Correspondences:
    """A return m of fibre j for every candidate return p of fibre i (j a neighbour of i).

    m is the return of fibre j nearest to p; with sight (returns.sight_at), every return is
    represented by its stand-in, and m is, of the LINE_CANDIDATES stand-ins of fibre j nearest p's,
    the one whose line of sight passes nearest p's stand-in (among those within LINE_REACH_M of it).
    Range noise moves a return along its own line of sight, so neither p's nor m's own noise moves
    the choice; with the measured points it does: on the ground, seen at a grazing angle, noise moves
    returns mostly along the ground, the nearest of the many returns of the next ring is the one whose
    noise brought it closest, and the same noise lifted or lowered it (measured on sim2_street with 1 cm
    range noise: the range offsets 3x their Cramér-Rao bound, worse with denser clouds); and which m a
    noisy p finds ties m's range, which weighs its fibre's offsets in the pair's Jacobian, to p's noise.

    A pair is kept when |p - m| < gates.gate_m, both p and m are planar enough (planarity >=
    gates.min_planarity) and lie on the same surface (|n_p . n_m| >= gates.min_normal_cos, and m within
    gates.max_plane_distance_m of the plane at p): pairs across an edge, or between two parallel faces
    (a car's cabin side above its body side), would pull the offsets even at the true calibration. Weight = planarity at p (eq. 4.4
    w_ijk). The features describe every point; candidates are the rows that may be p (all if None).
    gates.most subsamples each (i, j) pair's correspondences at random (rng)."""
    points_m, fibre, features, sight = cloud.points_m, cloud.fibre, cloud.features, cloud.sight
    candidates = np.arange(len(points_m)) if candidates is None else np.asarray(candidates)
    rng = rng or np.random.default_rng(0)
    by_fibre = rows_by_fibre(fibre)
    stand_ins = cloud.stand_ins_m
    trees = {f: cKDTree(stand_ins[rows], balanced_tree=False, compact_nodes=False) for f, rows in by_fibre.items()}
    planar = features.planarity >= gates.min_planarity
    planar_candidates = candidates[planar[candidates]]
    candidate_fibre = fibre[planar_candidates]
    p_of = {i: planar_candidates[candidate_fibre == i] for i in by_fibre}
    jobs = [(i, j) for i in by_fibre for j in neighbours.get(i, []) if j in trees and len(p_of[i])]
    streams = rng.spawn(len(jobs))  # one random stream per fibre pair: the same draws in any thread order

    def pairs_of(job: tuple[int, int], stream: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        i, j = job
        return _pairs_with((p_of[i], by_fibre[j]), trees[j], cloud, planar, gates, stream)

    # the KD-tree queries and NumPy release the GIL: fibre pairs side by side on the cores
    with ThreadPoolExecutor(usable_cores()) as pool:
        parts = list(pool.map(pairs_of, jobs, streams))
    if not parts:
        empty = np.zeros(0, dtype=np.int64)
        return Correspondences(empty, empty, np.zeros((0, 3)), np.zeros(0), out_of_plane_m=np.zeros(0))
    index_p = np.concatenate([p for p, _ in parts])
    index_m = np.concatenate([m for _, m in parts])
    shifts = (None, None) if sight is None else (sight.shift_m[index_p], sight.shift_m[index_m])
    return Correspondences(index_p, index_m, features.normal[index_p], features.planarity[index_p], *shifts,
                           features.out_of_plane_m[index_p])


def _nearest(p: np.ndarray, j_rows: np.ndarray, tree: cKDTree, cloud: PairCloud, gate_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(found mask over p, m rows of the found): each p's nearest return of fibre j within gate_m (tree),
    or with a sight, of the LINE_CANDIDATES stand-ins nearest p's stand-in, the one whose line of sight
    passes nearest p's stand-in among those within LINE_REACH_M of it (the nearest when none is): neither p's
    nor m's own range noise moves the choice."""
    if cloud.sight is None:
        distance, nearest = tree.query(cloud.points_m[p], k=1, distance_upper_bound=gate_m)
        found = np.isfinite(distance)
        return found, j_rows[nearest[found]]
    k = min(LINE_CANDIDATES, len(j_rows))
    stand_ins, rays = cloud.stand_ins_m, cloud.sight.rays
    distance, nearest = tree.query(stand_ins[p], k=k, distance_upper_bound=gate_m)
    distance, nearest = distance.reshape(len(p), k), nearest.reshape(len(p), k)
    found = np.isfinite(distance[:, 0])
    distance = distance[found]
    inside = np.isfinite(distance) & ((distance <= LINE_REACH_M) | (np.arange(k) == 0))
    m = j_rows[np.where(inside, nearest[found], 0)]  # (n, k); candidates beyond the gate or the reach masked below
    offset = stand_ins[p[found]][:, None, :] - cloud.points_m[m]
    along = np.einsum("nki,nki->nk", offset, rays[m])
    off_line = np.where(inside, np.einsum("nki,nki->nk", offset, offset) - along * along, np.inf)
    return found, m[np.arange(len(m)), np.argmin(off_line, axis=1)]


def _pairs_with(rows: tuple[np.ndarray, np.ndarray], tree: cKDTree, cloud: PairCloud, planar: np.ndarray,
                gates: PairGates, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(p, m) rows: the candidates p_rows paired with a return of fibre j (rows j_rows, in tree; rows =
    (p_rows, j_rows)), with planar the mask of returns planar enough, as associate keeps them; at most gates.most,
    a uniform random subset of those kept: the candidates are taken in a random order and only as many are
    searched as it takes to keep that many."""
    p_rows, j_rows = rows
    most = gates.most
    if most is not None:
        p_rows = p_rows[rng.permutation(len(p_rows))]
    chunk = 100_000 if most is None else 2 * most
    features, points = cloud.features, cloud.points_m
    kept_p, kept_m, count = [], [], 0
    for start in range(0, len(p_rows), chunk):
        p = p_rows[start:start + chunk]
        found, m = _nearest(p, j_rows, tree, cloud, gates.gate_m)
        p = p[found]
        normal = features.normal[p]
        same_surface = (planar[m]
                        & (np.abs(np.einsum("ni,ni->n", normal, features.normal[m])) >= gates.min_normal_cos)
                        & (np.abs(np.einsum("ni,ni->n", normal, points[p] - points[m])) <= gates.max_plane_distance_m))
        kept_p.append(p[same_surface])
        kept_m.append(m[same_surface])
        count += int(same_surface.sum())
        if most is not None and count >= most:
            break
    p, m = np.concatenate(kept_p)[:most], np.concatenate(kept_m)[:most]
    order = np.argsort(p, kind="stable")
    return p[order], m[order]
