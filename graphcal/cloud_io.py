"""Point cloud files: binary PLY, LAS/LAZ (laspy) and 3DTK's uos scans, written atomically.

Every writer takes xyz (N,3) [m] and named per-point columns (time [s], fibre, intensity ...),
which become PLY properties or LAS extra dimensions ("time" is the LAS GPS time and
"intensity" the LAS intensity, 0-255 as recorded). A pyproj CRS, when given, goes into the LAS
header (WKT VLR) and into a PLY comment line ("comment crs <EPSG or WKT>").
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from graphcal.atomic import atomic_path
from graphcal.errors import ConfigError, RecordingError

FORMATS = ("ply", "las", "laz", "uos")
# the PLY types that common readers (open3d, CloudCompare) all take; other integers become int
_PLY_TYPES = {np.dtype(np.float64): "double", np.dtype(np.float32): "float", np.dtype(np.int32): "int",
              np.dtype(np.uint8): "uchar"}
LAS_SCALE_M = 1e-4  # coordinates stored to 0.1 mm
LAS_MAX_SPAN_M = (2**31 - 1) * LAS_SCALE_M  # int32 steps from the offset: 214 km


def _columns(xyz_m: np.ndarray, columns: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    xyz_m = np.asarray(xyz_m, dtype=np.float64)
    out = {"x": xyz_m[:, 0], "y": xyz_m[:, 1], "z": xyz_m[:, 2]}
    for name, values in columns.items():
        values = np.asarray(values)
        if values.shape != (len(xyz_m),):
            raise ValueError(f"column {name!r} has shape {values.shape}, expected ({len(xyz_m)},)")
        if values.dtype not in _PLY_TYPES:
            values = values.astype(np.float64 if values.dtype.kind == "f" else np.int32)  # (u)int16, int64 ...
        out[name] = values
    return out


def write_ply(path: str | Path, xyz_m: np.ndarray, *, crs=None, **columns: np.ndarray) -> Path:
    """Binary little-endian PLY: x, y, z as double, then each column with its own type."""
    fields = _columns(xyz_m, columns)
    record = np.empty(len(xyz_m), dtype=[(name, values.dtype.newbyteorder("<")) for name, values in fields.items()])
    for name, values in fields.items():
        record[name] = values
    header = ["ply", "format binary_little_endian 1.0", "comment written by graphcal"]
    if crs is not None:
        header.append(f"comment crs {crs.to_string() if crs.to_epsg() else crs.to_wkt()}")
    header.append(f"element vertex {len(record)}")
    header += [f"property {_PLY_TYPES[values.dtype]} {name}" for name, values in fields.items()]
    header += ["end_header"]
    path = Path(path)
    with atomic_path(path) as tmp, open(tmp, "wb") as stream:
        stream.write(("\n".join(header) + "\n").encode("ascii"))
        stream.write(record.tobytes())
    return path


def write_las(path: str | Path, xyz_m: np.ndarray, *, crs=None, **columns: np.ndarray) -> Path:
    """LAS 1.4 point format 6 (LAZ when the name ends in .laz), coordinates to 0.1 mm from an
    offset at the cloud's minimum corner (whole metres), the pyproj `crs` in the header.

    "time" fills the GPS time [s] and "intensity" the intensity; other columns are extra
    dimensions of their own type."""
    import laspy

    path = Path(path)
    fields = _columns(xyz_m, columns)
    header = laspy.LasHeader(point_format=6, version="1.4")
    xyz_m = np.asarray(xyz_m, dtype=np.float64)
    header.offsets = np.floor(xyz_m.min(axis=0)) if len(xyz_m) else np.zeros(3)
    header.scales = np.full(3, LAS_SCALE_M)
    if len(xyz_m) and np.any(xyz_m.max(axis=0) - header.offsets >= LAS_MAX_SPAN_M):
        raise ConfigError(f"{path}: the cloud spans {np.ptp(xyz_m, axis=0).max() / 1e3:.0f} km, more than LAS "
                          f"integers hold at {LAS_SCALE_M} m steps ({LAS_MAX_SPAN_M / 1e3:.0f} km): write a PLY")
    if crs is not None:
        header.add_crs(crs)
    extra = [name for name in fields if name not in ("x", "y", "z", "time", "intensity")]
    header.add_extra_dims([laspy.ExtraBytesParams(name=name, type=fields[name].dtype) for name in extra])
    las = laspy.LasData(header)
    las.x, las.y, las.z = fields["x"], fields["y"], fields["z"]
    if "time" in fields:
        las.gps_time = fields["time"]
    if "intensity" in fields:
        las.intensity = np.clip(np.rint(fields["intensity"]), 0, 65535).astype(np.uint16)
    for name in extra:
        las[name] = fields[name]
    with atomic_path(path) as tmp, open(tmp, "wb") as stream:
        las.write(stream, do_compress=path.suffix.lower() == ".laz")
    return path


# 3DTK works in a left-handed frame, x right, y up, z forward, in cm; its own readers map a
# right-handed metric point (x forward, y left, z up) to (-100 y, 100 z, 100 x).
_TO_3DTK = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
_CM_PER_M = 100.0


def write_uos(path: str | Path, xyz_m: np.ndarray) -> Path:
    """3DTK's uos scan (scanNNN.3d): one 'x y z' line per point, in 3DTK's frame and cm."""
    with atomic_path(path) as tmp:
        np.savetxt(tmp, _CM_PER_M * np.asarray(xyz_m) @ _TO_3DTK.T, fmt="%.3f")
    return Path(path)


def write_cloud(path: str | Path, xyz_m: np.ndarray, *, crs=None, **columns: np.ndarray) -> Path:
    """Write by the file's suffix: .ply, .las, .laz or .3d (uos, xyz only, no CRS)."""
    suffix = Path(path).suffix.lower()
    if suffix == ".ply":
        return write_ply(path, xyz_m, crs=crs, **columns)
    if suffix in (".las", ".laz"):
        return write_las(path, xyz_m, crs=crs, **columns)
    if suffix == ".3d":
        return write_uos(path, xyz_m)
    raise ValueError(f"{path}: unknown point cloud suffix (expected .ply, .las, .laz or .3d)")


def pose_to_3dtk(rotation_matrix: np.ndarray, position_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A pose (p_parent = R p + X, right-handed, m) -> 3DTK's .pose values: position [cm] and
    Euler angles [deg] (theta_x, theta_y, theta_z) with R_3dtk = Rx Ry Rz (3DTK's EulerToMatrix4),
    both in 3DTK's left-handed frame. The angles are chosen as 3DTK's Matrix4ToEuler does
    (theta_y beyond +-90 deg rather than flipping theta_x and theta_z), so a yaw stays one angle."""
    M = _TO_3DTK @ np.asarray(rotation_matrix) @ _TO_3DTK.T
    sin_y = np.clip(M[0, 2], -1.0, 1.0)
    theta_y = np.arcsin(sin_y) if M[0, 0] > 0 else np.pi - np.arcsin(sin_y)
    cos_y = np.cos(theta_y)
    if abs(cos_y) > 0.005:
        theta_x = np.arctan2(-M[1, 2] / cos_y, M[2, 2] / cos_y)
        theta_z = np.arctan2(-M[0, 1] / cos_y, M[0, 0] / cos_y)
    else:  # gimbal lock, as 3DTK
        theta_x, theta_z = 0.0, np.arctan2(M[1, 0], M[1, 1])
    angles = np.degrees([theta_x, theta_y, theta_z])
    return _CM_PER_M * _TO_3DTK @ np.asarray(position_m, dtype=np.float64), angles


def pose_from_3dtk(position_cm: np.ndarray, angles_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of pose_to_3dtk: (rotation matrix, position m) in the right-handed frame."""
    from scipy.spatial.transform import Rotation

    R_3dtk = Rotation.from_euler("XYZ", angles_deg, degrees=True).as_matrix()
    return _TO_3DTK.T @ R_3dtk @ _TO_3DTK, _TO_3DTK.T @ np.asarray(position_cm, dtype=np.float64) / _CM_PER_M


def write_3dtk_pose(path: str | Path, rotation_matrix: np.ndarray, position_m: np.ndarray) -> Path:
    """scanNNN.pose: the position line [cm] and the Euler-angle line [deg] that 3DTK reads."""
    position_cm, angles_deg = pose_to_3dtk(rotation_matrix, position_m)
    with atomic_path(path) as tmp:
        tmp.write_text(" ".join(f"{v:.6f}" for v in position_cm) + "\n" + " ".join(f"{v:.9f}" for v in angles_deg)
                       + "\n")
    return Path(path)


def read_3dtk_pose(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """A .pose file -> (rotation matrix, position m) in the right-handed metric frame."""
    values = np.array(Path(path).read_text().split(), dtype=np.float64)
    if values.shape != (6,):
        raise RecordingError(path, f"{values.size} numbers", expected="6 numbers: position [cm], Euler angles [deg]")
    return pose_from_3dtk(values[:3], values[3:])
