"""Deskewed revolutions on disk: one cloud and one 3DTK pose per revolution, poses.csv, deskew.yaml.

    DIR/scan000.ply|.las|.laz|.3d   the revolution in its end-of-scan lidar frame L_end [m]
                                    (.3d: 3DTK's uos scan, in 3DTK's frame and cm)
    DIR/scan000.pose                T_world_lidar_end relative to origin_m, in 3DTK's convention
    DIR/poses.csv                   T_world_lidar_end per revolution in the world CRS (m, deg)
    DIR/deskew.yaml                 what was written, from what, in which frame
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np

from graphcal.common.atomic import atomic_directory
from graphcal.clouds.formats import FORMATS, write_3dtk_pose, write_cloud
from graphcal.common.errors import ConfigError
from graphcal.recording.rotations import rpy_deg_from_rotation
from graphcal.common.tables import write_csv_columns
from graphcal.common.yamlfile import write_yaml

FORMAT = "graphcal-deskew/1"
POSE_COLUMNS = ("scan", "scan_id", "time", "x", "y", "z", "roll", "pitch", "yaw", "returns")
_SUFFIX = {"ply": ".ply", "las": ".las", "laz": ".laz", "uos": ".3d"}


def scan_name(index: int) -> str:
    """3DTK's file stem: scan000, scan001, ... (more digits past 999)."""
    return f"scan{index:03d}"


def save_scans(scans: Iterable, directory: str | Path, cloud_format: str = "ply", manifest: dict | None = None) -> Path:
    """Write deskewed revolutions (graphcal.deskewing.deskew.Scan, in order) into `directory`, atomically.

    manifest: extra fields of deskew.yaml (recording, source, crs ...)."""
    if cloud_format not in FORMATS:
        raise ConfigError(f"cloud format {cloud_format!r}: expected one of {', '.join(FORMATS)}")
    directory = Path(directory)
    rows, origin, n_returns = [], None, 0
    with atomic_directory(directory) as tmp:
        for scan in scans:
            rotation = scan.rotation_world_lidar.as_matrix()
            if origin is None:  # 3DTK keeps points in float: its poses are relative to a local origin
                origin = np.floor(scan.position_world_lidar_m)
            name = scan_name(scan.index)
            write_cloud(tmp / f"{name}{_SUFFIX[cloud_format]}", scan.xyz_m, time=scan.time_s, fibre=scan.fibre,
                        intensity=scan.intensity)
            write_3dtk_pose(tmp / f"{name}.pose", rotation, scan.position_world_lidar_m - origin)
            rows.append([scan.index, scan.scan_id, scan.time_end_s, *scan.position_world_lidar_m,
                         *rpy_deg_from_rotation(scan.rotation_world_lidar), len(scan.xyz_m)])
            n_returns += len(scan.xyz_m)
        write_csv_columns(tmp / "poses.csv", POSE_COLUMNS, np.array(rows).reshape(-1, len(POSE_COLUMNS)),
                          formats=["%d", "%d", "%.9f", "%.6f", "%.6f", "%.6f", "%.8f", "%.8f", "%.8f", "%d"])
        write_yaml(tmp / "deskew.yaml", {
            "format": FORMAT, **(manifest or {}), "frame": "end-of-scan lidar frame (L_end), m",
            "cloud_format": cloud_format, "scans": len(rows), "returns": n_returns,
            "pose_origin_m": [float(v) for v in (origin if origin is not None else np.zeros(3))],
            "pose_convention": "scanNNN.pose: 3DTK (left-handed x right, y up, z forward; position cm relative to "
                               "pose_origin_m; angles deg, R = Rx Ry Rz); poses.csv: world CRS, m, "
                               "R = Rz(yaw) Ry(pitch) Rx(roll) deg"})
    return directory
