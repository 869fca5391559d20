"""A simulation of a recording's own drive when there is no scene model: the calibrated cloud is
meshed (open3d Poisson, normals turned towards each return's sensor), then every return's ray of
the calibrated model, at its own time, is cast against the mesh. The result is a recording with the
same returns and simulated ranges: graphcal's model with nominal physics, on the recording's scene.
"""

from __future__ import annotations

from dataclasses import replace

import gtsam
import numpy as np
import open3d as o3d

from factors.spherical import beam_rays
from graphcal.calibration.returns import Estimate, ReturnData, prepare, world_at
from graphcal.recording.points import PointTable
from graphcal.recording.directory import Recording

POISSON_DEPTH = 11
DENSITY_QUANTILE = 0.05  # mesh vertices supported by fewer points than this share are dropped


def with_controls(estimate: Estimate, data: ReturnData) -> Estimate:
    """The estimate's offsets and extrinsic with no trajectory correction at data's control times."""
    return replace(estimate, corrections=tuple(gtsam.Pose3() for _ in data.control_times_s))


def mesh_of(points_m: np.ndarray, sensor_m: np.ndarray) -> o3d.geometry.TriangleMesh:
    """Poisson mesh [m] of a cloud (N,3) whose normals are turned towards each point's sensor (N,3)."""
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points_m))
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.5, max_nn=20))
    normals = np.asarray(cloud.normals)
    flip = np.einsum("ni,ni->n", normals, sensor_m - points_m) < 0
    normals[flip] *= -1.0
    cloud.normals = o3d.utility.Vector3dVector(normals)
    mesh, density = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(cloud, depth=POISSON_DEPTH)
    density = np.asarray(density)
    mesh.remove_vertices_by_mask(density < np.quantile(density, DENSITY_QUANTILE))
    return mesh


def rescan(recording: Recording, estimate: Estimate, max_points: int | None = 400_000, seed: int = 0) -> Recording:
    """The recording's returns (a random subset of max_points) with ranges raycast on the mesh of its
    cloud, placed by estimate (offsets and extrinsic; no trajectory correction); misses dropped."""
    data = prepare(recording, np.inf, max_points, np.random.default_rng(seed))
    estimate = with_controls(estimate, data)
    points = world_at(data, estimate, pose=False)
    R_E, t_E = estimate.extrinsic.rotation().matrix(), estimate.extrinsic.translation()
    sensor = data.X_nav + np.einsum("nij,j->ni", data.R_nav, t_E)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh_of(points, sensor)))
    factory = data.sensor.factory_terms(data.fibre)
    offsets = estimate.offsets[data.fibre]
    origin_l, direction_l = beam_rays(data.azimuth_rad, factory, offsets)
    origin = np.einsum("nij,nj->ni", data.R_nav, origin_l @ R_E.T + t_E) + data.X_nav
    direction = np.einsum("nij,nj->ni", data.R_nav, direction_l @ R_E.T)
    hit = scene.cast_rays(o3d.core.Tensor(np.hstack([origin, direction]).astype(np.float32)))
    distance = hit["t_hit"].numpy().astype(np.float64)
    kept = np.isfinite(distance)
    # beam_rays' origin is where the corrected range r = rho + d_rho + r0 - B (B: beam origin) is zero
    range_m = distance - offsets[:, 0] - factory.range_offset_m + factory.beam_origin_m
    columns = recording.points.read()
    rows = data.rows[kept]
    arrays = {name: values[rows] for name, values in columns.items()}
    arrays["range"] = range_m[kept]
    return replace(recording, name=recording.name + "-rescan", points=PointTable.from_arrays(**arrays), path=None,
                   _truth=None)
