"""The block factors' data of a calibration (factors/point_to_plane.py): one block per fibre of p and
window of block_controls control intervals of p (per window only when the intrinsics are not estimated) and, with
trajectory corrections, per few windows of m (M_WINDOWS), the fibres merged up to MIN_BLOCK_ROWS pairs, at most
MAX_BLOCK_ROWS pairs each, with each pair's sigma."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from factors.point_to_plane import NO_KEY, Block, BlockKeys, FixedValues, incidence_sigma_m, pose_noise_sigma_m
from factors.world_point import normals_to_lidar, on_stand_ins
from graphcal.calibration.association import Correspondences
from graphcal.calibration.config import CalibrationConfig
from graphcal.calibration.keys import E, I, X
from graphcal.calibration.returns import Estimate, ReturnData, corrections_at, rays_at, world_at

MAX_BLOCK_ROWS = 20_000
MIN_BLOCK_ROWS = 2_000
M_WINDOWS = 8  # windows of m's controls one block ties at most (besides p's own)


def make_blocks(data: ReturnData, estimate: Estimate, pairs: Correspondences, config: CalibrationConfig,
                estimated: tuple[bool, bool, bool], effects=None) -> Iterator[tuple[np.ndarray, Block]]:
    """The block factors' data, one block at a time, each with its rows in pairs; effects.terms(p_rows, m_rows)
    gives each block's candidate effects (graphcal.diagnosis; None: none)."""
    est_int, est_ext, est_traj = estimated
    pose = config.trajectory.pose_corrections
    ref = config.priors.fixed_fibre(data.sensor.reference_fibre)
    normal_lidar = normals_to_lidar(data.returns(pairs.index_p), estimate.extrinsic.rotation().matrix(),
                                    corrections_at(estimate, data.control[pairs.index_p], pose), pairs.normal)
    fi, fj = data.fibre[pairs.index_p], data.fibre[pairs.index_m]
    cp, cm = data.control[pairs.index_p], data.control[pairs.index_m]
    sigma = pair_sigma_m(data, estimate, pairs, config)
    intrinsic_key = np.array([NO_KEY if f == ref else I(f) for f in range(data.sensor.n_fibres)], np.int64)
    control_key = np.array([X(c) for c in range(len(data.control_times_s))], np.int64)
    window_p = cp // config.trajectory.block_controls if est_traj else 0 * cp
    window_m = cm // config.trajectory.block_controls if est_traj else None
    for rows in block_rows(fi if est_int else np.zeros_like(fi), window_p, window_m):
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
        yield rows, block


def pair_sigma_m(data: ReturnData, estimate: Estimate, pairs: Correspondences, config: CalibrationConfig) -> np.ndarray:
    """Each pair's sigma [m]: sigma0 (pair_noise uniform), or the range noise along the pair's two lines of
    sight with the plane model's error and the trajectory's jitter (incidence; docs/reference/math.md)."""
    sigma0 = config.weighting.sigma0_m
    if config.weighting.pair_noise != "incidence":
        return np.full(len(pairs), sigma0)
    return incidence_sigma_m(pairs.normal, rays_at(data, estimate, pairs.index_p), rays_at(data, estimate, pairs.index_m),
                             sigma0, np.hypot(plane_model_sigma_m(pairs, config), pose_sigma_m(data, estimate, pairs)))


def plane_model_sigma_m(pairs: Correspondences, config: CalibrationConfig) -> np.ndarray | float:
    """Each pair's plane-model sigma [m] for its incidence sigma: the out-of-plane scatter of p's
    neighbourhood, where the features follow the fit; 0 on fixed pairs (association.fixed), whose features
    stay those of the start: their scatter there holds the start's own errors between rings, which the fit
    is to remove, and would weigh those pairs down."""
    if config.association.fixed or pairs.out_of_plane_m is None:
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


def block_rows(fibre_p: np.ndarray, window: np.ndarray, window_m: np.ndarray | None = None,
               min_rows: int = MIN_BLOCK_ROWS, max_rows: int = MAX_BLOCK_ROWS) -> list[np.ndarray]:
    """Pair indices of each block: the pairs of one fibre of p and one window of p's control intervals (and, given
    window_m, each pair's window of m's, of a few of them: m_buckets), the fibres of one window merged in
    elevation-index order until a block holds at least min_rows pairs (a long drive spreads the capped pairs thin
    over its windows: without merging, its blocks, each one Python callback, would grow in number with the drive
    and shrink in rows; merging windows instead would tie every control of a block to every other in its compressed
    factor, and the graph's elimination with them), in chunks of at most max_rows."""
    if not len(fibre_p):
        return []
    if window_m is not None:
        window = m_buckets(window, window_m, min_rows)
    group = window.astype(np.int64) * (int(fibre_p.max()) + 1) + fibre_p
    order = np.argsort(group, kind="stable")
    bounds = np.flatnonzero(np.r_[True, np.diff(group[order]) != 0, True])
    blocks = []
    for start, stop in _merged(bounds, window[order[bounds[:-1]]], min_rows):
        blocks += np.array_split(order[start:stop], -(-(stop - start) // max_rows))
    return blocks


def m_buckets(window_p: np.ndarray, window_m: np.ndarray, min_rows: int, most: int = M_WINDOWS) -> np.ndarray:
    """Each pair's bucket, numbered in the order of p's windows: the pairs of one window of p, in the order of m's
    windows, cut where a bucket reaches min_rows pairs or most windows of m. Revisits pair a window of p with
    returns of every pass that saw its surfaces (on a city loop most pairs join passes seconds to minutes apart):
    one block over all of them would tie the controls of every pass in one dense factor, whose width, and the
    elimination's cost, grow with the drive."""
    span = int(window_m.max()) + 1
    groups, group_of, counts = np.unique(window_p.astype(np.int64) * span + window_m, return_inverse=True,
                                         return_counts=True)  # (p's window, m's) in lexicographic order
    group_p = (groups // span).tolist()
    bucket_of_group = np.zeros(len(groups), np.int64)
    bucket, rows, windows = -1, 0, 0
    for g, (p, count) in enumerate(zip(group_p, counts.tolist())):
        if g == 0 or p != group_p[g - 1] or rows >= min_rows or windows >= most:
            bucket, rows, windows = bucket + 1, 0, 0
        bucket_of_group[g] = bucket
        rows, windows = rows + count, windows + 1
    return bucket_of_group[group_of.ravel()]


def _merged(bounds: np.ndarray, window_of: np.ndarray, min_rows: int) -> list[tuple[int, int]]:
    """(start, stop) of the merged groups: successive groups (rows bounds[k]:bounds[k + 1], of window
    window_of[k]) of one window joined until they hold min_rows rows; a window's short remainder joins its
    last span."""
    spans: list[tuple[int, int]] = []
    ends = np.flatnonzero(np.r_[window_of[1:] != window_of[:-1], True])  # each window's last group
    first = 0
    for last in ends:
        start, own = int(bounds[first]), len(spans)
        for k in range(first, last + 1):
            if bounds[k + 1] - start >= min_rows:
                spans.append((start, int(bounds[k + 1])))
                start = int(bounds[k + 1])
        stop = int(bounds[last + 1])
        if start < stop and len(spans) > own:  # the remainder extends the window's last span
            spans[-1] = (spans[-1][0], stop)
        elif start < stop:  # or is the window's only one
            spans.append((start, stop))
        first = last + 1
    return spans
