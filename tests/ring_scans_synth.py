"""Synthetic ringed scans for the PCD and PointCloud2 importer tests: known raw returns turned into the
corrected x, y, z a driver writes, with ring (velodyne_pointcloud numbering: rank by elevation) and time."""

from __future__ import annotations

import numpy as np
import yaml

from graphcal.recording.sensor import SensorModel

START_UTC = 1_700_000_000.25  # s since 1970
PERIOD_S = 0.1


def sensor(with_offsets: bool) -> SensorModel:
    """A 16-laser head in firing order (interleaved elevations), with vertical offsets; with_offsets adds
    per-laser azimuth, range and horizontal offsets (terms only a calibration file can give back)."""
    n = 16
    elevation = np.array([-15, 1, -13, 3, -11, 5, -9, 7, -7, 9, -5, 11, -3, 13, -1, 15], dtype=np.float64) + 0.1
    side = np.where(np.arange(n) % 2 == 0, 1.0, -1.0)
    zeros = np.zeros(n)
    return SensorModel(model="TEST-16", rotation_hz=1.0 / PERIOD_S, reference_fibre=15, elevation_deg=elevation,
                       azimuth_offset_deg=1.5 * side if with_offsets else zeros,
                       range_offset_m=0.01 * side + 0.02 if with_offsets else zeros,
                       vertical_offset_m=0.004 * np.arange(n) - 0.03,
                       horizontal_offset_m=0.02 * side if with_offsets else zeros, height_offset_m=zeros)


def write_ros_calibration(path, model: SensorModel) -> None:
    """A ROS velodyne_pointcloud calibration YAML of the model (angles rad, lengths m)."""
    lasers = [{"laser_id": i, "vert_correction": float(np.radians(model.elevation_deg[i])),
               "rot_correction": float(-np.radians(model.azimuth_offset_deg[i])),
               "dist_correction": float(model.range_offset_m[i]),
               "vert_offset_correction": float(model.vertical_offset_m[i]),
               "horiz_offset_correction": float(model.horizontal_offset_m[i])} for i in range(model.n_fibres)]
    path.write_text(yaml.safe_dump({"lasers": lasers, "num_lasers": model.n_fibres, "distance_resolution": 0.002}))


def scans(model: SensorModel, n_scans: int = 3, columns: int = 120, seed: int = 0) -> list[dict]:
    """n_scans revolutions: per return the true fibre, ring, range [m], encoder azimuth [rad], time [s since 1970],
    intensity, and the float32 x, y, z the driver writes; each scan's stamp is its first firing."""
    rng = np.random.default_rng(seed)
    ring_of_fibre = np.argsort(model.fibres_by_elevation())
    out = []
    for k in range(n_scans):
        stamp = START_UTC + k * PERIOD_S
        column = np.repeat(np.arange(columns), model.n_fibres)
        fibre = np.tile(np.arange(model.n_fibres), columns)
        azimuth = np.mod(2 * np.pi * (column + 0.3) / columns, 2 * np.pi)  # clockwise from x, starting at 0
        time = stamp + PERIOD_S * (column + fibre / model.n_fibres) / columns
        range_m = rng.uniform(2.0, 80.0, fibre.size)
        xyz = model.to_xyz(fibre, range_m, azimuth).astype(np.float32)
        out.append({"stamp": stamp, "fibre": fibre, "ring": ring_of_fibre[fibre], "range": range_m,
                    "azimuth": azimuth, "time": time, "intensity": rng.integers(0, 256, fibre.size).astype(np.float32),
                    "xyz": xyz})
    return out


def kitti_poses(n: int, speed_m_s: float = 2.0) -> np.ndarray:
    """(n, 3, 4) poses of a straight drive along x with a slow turn, one per scan."""
    poses = np.zeros((n, 3, 4))
    for k in range(n):
        yaw = 0.02 * k
        poses[k, :, :3] = [[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]]
        poses[k, :, 3] = [speed_m_s * PERIOD_S * k, 0.1 * k, 0.0]
    return poses


def nearest(sorted_times: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Index of the nearest of sorted_times for each of times (returns matched by their own time)."""
    after = np.clip(np.searchsorted(sorted_times, times), 1, len(sorted_times) - 1)
    return np.where(np.abs(sorted_times[after] - times) < np.abs(sorted_times[after - 1] - times), after, after - 1)
