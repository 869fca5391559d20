"""Point cloud files: binary PLY, LAS/LAZ (laspy) and 3DTK's uos scans, written atomically.

Every writer takes xyz (N,3) [m] and named per-point columns (time [s], fibre, intensity ...),
which become PLY properties or LAS extra dimensions ("time" is the LAS GPS time and
"intensity" the LAS intensity, 0-255 as recorded). A pyproj CRS, when given, goes into the LAS
header (WKT VLR) and into a PLY comment line ("comment crs <EPSG or WKT>").
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from graphcal.common.atomic import atomic_path
from graphcal.common.errors import ConfigError, RecordingError

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
    with ply_writer(path, len(xyz_m), crs=crs) as write:
        write(xyz_m, **columns)
    return Path(path)


@contextmanager
def ply_writer(path: str | Path, n_points: int, *, crs=None) -> Iterator[Callable[..., None]]:
    """write(xyz_m, **columns) chunk by chunk into one PLY of n_points (the header says how many
    first); every chunk has the same columns. The file appears when all n_points are written."""
    path = Path(path)
    with atomic_path(path) as tmp, open(tmp, "wb") as stream:
        written = 0

        def write(xyz_m: np.ndarray, **columns: np.ndarray) -> None:
            nonlocal written
            fields = _columns(xyz_m, columns)
            if stream.tell() == 0:
                header = ["ply", "format binary_little_endian 1.0", "comment written by graphcal"]
                if crs is not None:
                    header.append(f"comment crs {crs.to_string() if crs.to_epsg() else crs.to_wkt()}")
                header.append(f"element vertex {n_points}")
                header += [f"property {_PLY_TYPES[values.dtype]} {name}" for name, values in fields.items()]
                stream.write(("\n".join(header + ["end_header"]) + "\n").encode("ascii"))
            record = np.empty(len(xyz_m), dtype=[(name, v.dtype.newbyteorder("<")) for name, v in fields.items()])
            for name, values in fields.items():
                record[name] = values
            stream.write(record.tobytes())
            written += len(record)

        yield write
        if n_points == 0:
            write(np.empty((0, 3)))  # the header alone
        if written != n_points:
            raise ValueError(f"{path}: {written} points written, the header says {n_points}")


def write_las(path: str | Path, xyz_m: np.ndarray, *, crs=None, **columns: np.ndarray) -> Path:
    """LAS 1.4 point format 6 (LAZ when the name ends in .laz), coordinates to 0.1 mm from an
    offset at the cloud's minimum corner (whole metres), the pyproj `crs` in the header.

    "time" fills the GPS time [s] and "intensity" the intensity; other columns are extra
    dimensions of their own type."""
    offset = np.floor(np.asarray(xyz_m, dtype=np.float64).min(axis=0)) if len(xyz_m) else np.zeros(3)
    with las_writer(path, offset, crs=crs) as write:
        write(xyz_m, **columns)
    return Path(path)


@contextmanager
def las_writer(path: str | Path, offset_m: np.ndarray, *, crs=None) -> Iterator[Callable[..., None]]:
    """write(xyz_m, **columns) chunk by chunk into one LAS 1.4 / LAZ file (as write_las), the
    coordinates stored as integers of LAS_SCALE_M from offset_m (whole metres near the cloud):
    a point LAS_MAX_SPAN_M or more from it is refused. The header (bounds, counts) is completed
    at the end and the file appears then."""
    import laspy

    path = Path(path)
    from graphcal import __version__

    header = laspy.LasHeader(point_format=6, version="1.4")
    header.generating_software = f"graphcal {__version__}"
    header.offsets, header.scales = np.asarray(offset_m, dtype=np.float64), np.full(3, LAS_SCALE_M)
    if crs is not None:
        header.add_crs(crs)
    with atomic_path(path) as tmp, open(tmp, "wb") as stream:
        writer, written = None, 0

        def write(xyz_m: np.ndarray, **columns: np.ndarray) -> None:
            nonlocal writer, written
            fields = _columns(xyz_m, columns)
            extra = [name for name in fields if name not in ("x", "y", "z", "time", "intensity")]
            if writer is None:
                header.add_extra_dims([laspy.ExtraBytesParams(name=name, type=fields[name].dtype) for name in extra])
                writer = laspy.open(stream, mode="w", header=header, do_compress=path.suffix.lower() == ".laz",
                                    closefd=False)
            xyz = np.asarray(xyz_m, dtype=np.float64)
            finite = np.isfinite(xyz).all(axis=1)
            if not finite.all():  # laspy would store it as the most negative integer, silently
                raise ConfigError(f"{path}: point {written + int(np.argmin(finite))} has a coordinate that is not "
                                  "finite (NaN or inf): expected metres in the output CRS")
            if len(xyz) and np.abs(xyz - header.offsets).max() >= LAS_MAX_SPAN_M:
                raise ConfigError(f"{path}: points {np.abs(xyz - header.offsets).max() / 1e3:.0f} km from the "
                                  f"LAS offset, more than integers hold at {LAS_SCALE_M} m steps "
                                  f"({LAS_MAX_SPAN_M / 1e3:.0f} km): write a PLY")
            points = laspy.ScaleAwarePointRecord.zeros(len(xyz), header=header)
            points.x, points.y, points.z = fields["x"], fields["y"], fields["z"]
            if "time" in fields:
                points.gps_time = fields["time"]
            if "intensity" in fields:
                points.intensity = np.clip(np.rint(fields["intensity"]), 0, 65535).astype(np.uint16)
            for name in extra:
                points[name] = fields[name]
            writer.write_points(points)
            written += len(xyz)

        yield write
        if writer is None:
            write(np.empty((0, 3)))  # the header alone
        writer.close()


# 3DTK works in a left-handed frame, x right, y up, z forward, in cm; its own readers map a
# right-handed metric point (x forward, y left, z up) to (-100 y, 100 z, 100 x).
_TO_3DTK = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
_CM_PER_M = 100.0


def write_uos(path: str | Path, xyz_m: np.ndarray) -> Path:
    """3DTK's uos scan (scanNNN.3d): one 'x y z' line per point, in 3DTK's frame and cm."""
    with atomic_path(path) as tmp:
        np.savetxt(tmp, _CM_PER_M * np.asarray(xyz_m) @ _TO_3DTK.T, fmt="%.3f")
    return Path(path)


STREAMED_SUFFIXES = (".las", ".laz", ".ply")


def cloud_writer(path: str | Path, n_points: int, offset_m: np.ndarray, *, crs=None):
    """las_writer (offset_m: the LAS integer origin) or ply_writer by the file's suffix."""
    suffix = Path(path).suffix.lower()
    if suffix == ".ply":
        return ply_writer(path, n_points, crs=crs)
    if suffix in (".las", ".laz"):
        return las_writer(path, offset_m, crs=crs)
    raise ConfigError(f"{path}: expected a {', '.join(STREAMED_SUFFIXES)} file name")


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
