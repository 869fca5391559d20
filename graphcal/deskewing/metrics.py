"""The metrics of seed 002, section 4, plus the distance to truth the seed could not measure.

(a) ICP point-to-point error between successive revolutions (open3d), started from the INS
    relative pose of their end-of-scan frames, as 3DTK's scan matching is started from poses;
(b) the number of occupied cells (0.1 m) of the assembled cloud (Table 2): every revolution
    placed with its INS pose; a smeared cloud fills more cells;
(c) on simulated data, each return's distance to its true position when its revolution is
    placed with the TRUE end-of-scan lidar pose, so that only the deskew is measured.
Evaluation code: (c) reads truth/.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import open3d as o3d

from graphcal.recording.geodesy import to_world
from graphcal.clouds.metrics import DistanceStats

CELL_M = 0.1  # Table 2: cells of 0.1 m


def assembled_cloud(scans: Sequence) -> np.ndarray:
    """(N,3) world points [m]: every revolution placed with its INS end-of-scan pose."""
    return np.concatenate([scan.world_points() for scan in scans])


def occupied_cells(points_m: np.ndarray, cell_m: float = CELL_M) -> int:
    """Number of cubic cells of side cell_m [m] holding at least one point."""
    cells = np.floor((points_m - points_m.min(axis=0)) / cell_m).astype(np.int64)
    span = cells.max(axis=0) + 1
    return int(np.unique((cells[:, 0] * span[1] + cells[:, 1]) * span[2] + cells[:, 2]).size)


@dataclass(frozen=True)
class IcpPair:
    """ICP of revolution k onto k+1: inlier RMSE [m] of the point-to-point residuals and
    fitness (fraction of points with a correspondence)."""

    rmse_m: float
    fitness: float


def icp_errors(scans: Sequence, max_distance_m: float = 1.0, voxel_m: float = 0.1) -> list[IcpPair]:
    """Point-to-point ICP (open3d) of each revolution onto the next, in their L_end frames,
    started from their INS relative pose, on clouds thinned to one point per voxel_m."""
    clouds = [o3d.geometry.PointCloud(o3d.utility.Vector3dVector(scan.xyz_m)).voxel_down_sample(voxel_m)
              for scan in scans]
    pairs = []
    for k in range(len(scans) - 1):
        T_world_source, T_world_target = _matrix(scans[k]), _matrix(scans[k + 1])
        start = np.linalg.solve(T_world_target, T_world_source)
        result = o3d.pipelines.registration.registration_icp(
            clouds[k], clouds[k + 1], max_distance_m, start,
            o3d.pipelines.registration.TransformationEstimationPointToPoint())
        pairs.append(IcpPair(float(result.inlier_rmse), float(result.fitness)))
    return pairs


def _matrix(scan) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = scan.rotation_world_lidar.as_matrix()
    T[:3, 3] = scan.position_world_lidar_m
    return T


def truth_distance(scans: Sequence, recording) -> np.ndarray:
    """(N,) distance [m] of each return of the revolutions to its true world position, each
    revolution placed with the true T_world_lidar at its end (true trajectory and extrinsic).
    A scan has xyz_m, time_end_s, rows (its rows of points.parquet) and world_points(R, X)."""
    truth = recording.truth
    poses = to_world(truth.trajectory, recording.crs).poses
    true_points = truth.world_points()
    ends = np.array([scan.time_end_s for scan in scans])
    position, rotation = poses.interpolate(ends)
    rotation_lidar = rotation * truth.extrinsic.rotation
    position_lidar = position + rotation.apply(np.asarray(truth.extrinsic.lever_arm_m))
    distances = []
    for k, scan in enumerate(scans):
        placed = scan.world_points(rotation_lidar[k], position_lidar[k])
        distances.append(np.linalg.norm(placed - true_points[scan.rows], axis=1))
    return np.concatenate(distances)


@dataclass(frozen=True)
class DeskewMetrics:
    """Seed 002's metrics for one set of revolutions (raw or deskewed)."""

    icp_rmse_m: float  # mean over successive pairs
    occupied_cells: int
    truth: DistanceStats | None  # None for real data

    @classmethod
    def of(cls, scans: Sequence, recording) -> DeskewMetrics:
        pairs = icp_errors(scans)
        truth = DistanceStats.of(truth_distance(scans, recording)) if recording.truth is not None else None
        return cls(float(np.mean([p.rmse_m for p in pairs])) if pairs else float("nan"),
                   occupied_cells(assembled_cloud(scans)), truth)
