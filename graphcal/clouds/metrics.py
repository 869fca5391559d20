"""Cloud metrics against ground truth (evaluation only)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d


@dataclass(frozen=True)
class DistanceStats:
    """Distances [m]: mean, median, 95th percentile, max."""

    mean: float
    median: float
    p95: float
    max: float

    @classmethod
    def of(cls, distance_m: np.ndarray) -> DistanceStats:
        return cls(float(np.mean(distance_m)), float(np.median(distance_m)),
                   float(np.percentile(distance_m, 95)), float(np.max(distance_m)))

    def __str__(self) -> str:
        return (f"mean {self.mean * 100:.2f} cm, median {self.median * 100:.2f} cm, "
                f"p95 {self.p95 * 100:.2f} cm, max {self.max * 100:.2f} cm")


def cloud_to_cloud(points_m: np.ndarray, reference_m: np.ndarray) -> np.ndarray:
    """Distance [m] from each point to its nearest neighbour in the reference cloud (open3d).

    Both (N,3) in the same world frame; a common local origin is removed first.
    """
    origin = reference_m.mean(axis=0)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points_m - origin))
    reference = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(reference_m - origin))
    return np.asarray(cloud.compute_point_cloud_distance(reference))
