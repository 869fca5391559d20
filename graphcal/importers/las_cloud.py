"""A georeferenced LAS/LAZ cloud with GPS time + the trajectory it was made with (SBET) -> a recording.

A LAS file holds world points, not raw returns: the producer has already applied the sensor
model, the mounting (lever arm, boresight) and the trajectory. The importer undoes the last two
for every point at its own GPS time, with graphcal's forward model (graphcal.recording.georeference)

    p_body = R_world_body(t)^T (p_world - X_world_body(t)),  p_lidar = R_body_lidar^T (p_body - T)

in the LAS file's projected CRS (the header's WKT or GeoTIFF keys, or crs=...), and recovers the
raw values from p_lidar through a nominal model (beam_fit):
- the laser of each point: an extra-bytes dimension named ring, channel, laser_id or laser,
  else point_source_id when it takes more than one value (it usually holds the flight line);
  with none, the scanner is taken as a single beam;
- a single beam (an airborne line scanner): when no boresight is given, the scanner's axis is the
  normal of the plane its returns lie in (in the body frame, through the lever arm), fitted: the
  lidar frame has z along it and x pointing away from the mean return (the returns lie around
  azimuth 180 deg, clear of the 0/360 wrap); the boresight found is the recording's initial extrinsic;
- range = distance along the beam, azimuth = encoder angle about the lidar's z axis.
GPS time: LAS week time (GPS seconds of week) or adjusted standard GPS time (s since the GPS
epoch - 1e9), both turned into GPS seconds of week. Heights are taken as ellipsoidal (as SBET's).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from graphcal.common.errors import RecordingError
from graphcal.importers.beam_fit import misfit_note, ring_model
from graphcal.importers.gpstime import WEEK_S
from graphcal.importers.point_fields import intensity_0_255
from graphcal.importers.velodyne_calibration import VelodyneCalibration
from graphcal.recording.directory import Recording
from graphcal.recording.extrinsic import Extrinsic
from graphcal.recording.geodesy import to_world
from graphcal.recording.points import PointTable
from graphcal.recording.rotations import rpy_deg_from_rotation
from graphcal.recording.trajectory import Trajectory

RING_DIMENSIONS = ("ring", "channel", "laser_id", "laser")
_UTM_NORTH, _UTM_SOUTH = range(16001, 16061), range(16101, 16161)  # GeoTIFF ProjectionGeoKey codes
_ADJUSTED_OFFSET_S = 1e9


def las_crs(header, path: Path) -> str | None:
    """The file's projected CRS as 'EPSG:n' or WKT: the WKT/GeoTIFF VLRs (laspy), else the GeoTIFF
    ProjectedCSType (3072) or a WGS 84 UTM ProjectionGeoKey (3074); None when the file has none."""
    try:
        crs = header.parse_crs()
    except Exception:  # laspy's pyproj parse of a damaged or user-defined description
        crs = None
    if crs is not None:
        return crs.to_wkt()
    for vlr in header.vlrs:
        keys = {key.id: key.value_offset for key in getattr(vlr, "geo_keys", [])}
        if 0 < keys.get(3072, 32767) < 32767:
            return f"EPSG:{keys[3072]}"
        code = keys.get(3074)
        if code in _UTM_NORTH or code in _UTM_SOUTH:
            return f"EPSG:{32600 + code - 16000 if code in _UTM_NORTH else 32700 + code - 16100}"
    return None


def import_las(path: str | Path, trajectory: Trajectory, *, crs: str | None = None,
               lever_arm_m: tuple[float, float, float] = (0.0, 0.0, 0.0),
               boresight_deg: tuple[float, float, float] | None = None,
               calibration: VelodyneCalibration | None = None, ring_field: str | None = None,
               name: str | None = None) -> Recording:
    """A LAS/LAZ file and its trajectory (GPS seconds of week) as a recording; see the module docstring.
    lever_arm_m, boresight_deg: the lidar -> body mounting the cloud was made with (boresight None: identity,
    or fitted for a single beam)."""
    import laspy

    path = Path(path)
    if not path.is_file():
        raise RecordingError(path, "file not found")
    try:
        las = laspy.read(path)
    except Exception as error:  # laspy's own: not a LAS file, a cut one, LAZ without a backend
        raise RecordingError(path, f"not a readable LAS/LAZ file: {type(error).__name__}: {error}",
                             expected="a LAS or LAZ file (LAZ needs lazrs)") from None
    dimensions = list(las.point_format.dimension_names)
    if "gps_time" not in dimensions:
        raise RecordingError(path, f"point format {las.header.point_format.id} has no GPS time", field="gps_time",
                             expected="a point format with gps_time (1, 3, 4, 5, 6 and above)")
    crs = crs or las_crs(las.header, path)
    if crs is None:
        raise RecordingError(path, "no CRS in the header", field="crs",
                             expected="a WKT or GeoTIFF CRS in the file, or --crs (e.g. EPSG:32611)")
    time, time_note = _week_seconds(np.asarray(las.gps_time, dtype=np.float64), las.header)
    ring, ring_note = _rings(las, dimensions, ring_field, path)
    notes = [f"{len(time)} points of {path.name} (LAS {las.header.version}, point format "
             f"{las.header.point_format.id}), CRS {crs if crs.startswith('EPSG') else 'from the header (WKT)'}",
             time_note, ring_note]
    inside = (time >= trajectory.time[0]) & (time <= trajectory.time[-1])
    if not inside.any():
        raise RecordingError(path, f"GPS times [{time.min():.3f}, {time.max():.3f}] s of week outside the trajectory's "
                                   f"[{trajectory.time[0]:.3f}, {trajectory.time[-1]:.3f}]",
                             field="gps_time", expected="the trajectory the cloud was made with")
    notes.append(f"{int((~inside).sum())} points outside the trajectory's time span left out")
    order = np.argsort(time[inside], kind="stable")
    rows = np.flatnonzero(inside)[order]
    time, ring = time[rows], ring[rows]
    world = np.column_stack([np.asarray(las.x)[rows], np.asarray(las.y)[rows], np.asarray(las.z)[rows]])
    poses = to_world(trajectory, crs, path).poses
    position, rotation = poses.interpolate(time)
    p_body = rotation.inv().apply(world - position)
    extrinsic, mount_note = _mounting(p_body, ring, tuple(float(v) for v in lever_arm_m), boresight_deg)
    notes.append(mount_note)
    p_lidar = extrinsic.rotation.inv().apply(p_body - np.asarray(extrinsic.lever_arm_m))
    rotation_hz = _rotation_hz(p_lidar, time)
    model = ring_model(p_lidar, ring, "LAS", rotation_hz, path, calibration)
    fibre, range_m, azimuth, misfit = model.raw(ring, p_lidar)
    intensity, intensity_note = intensity_0_255(np.asarray(las.intensity, dtype=np.float64)[rows])
    notes += [*model.notes, misfit_note(misfit), intensity_note, *_limits(model.sensor.n_fibres)]
    source = {"importer": "las", "file": path.name, "model": "LAS", "time_base": "GPS seconds of week",
              "notes": notes}
    points = PointTable.from_arrays(time=time, fibre=fibre, range=range_m, azimuth=azimuth, intensity=intensity)
    return Recording(name=name or path.stem, crs=crs, sensor=model.sensor, extrinsic=extrinsic,
                     trajectory=trajectory, points=points, source=source)


def _week_seconds(gps_time: np.ndarray, header) -> tuple[np.ndarray, str]:
    """LAS GPS times -> GPS seconds of week (of the first point's week for adjusted standard time)."""
    adjusted = bool(int(header.global_encoding.value) & 1)
    if not adjusted:
        return gps_time, "gps_time read as GPS seconds of week (the header's GPS week time flag)"
    seconds = gps_time + _ADJUSTED_OFFSET_S
    week = int(np.floor(seconds.min() / WEEK_S))
    return seconds - week * WEEK_S, f"gps_time read as adjusted standard GPS time, turned into seconds of week {week}"


def _rings(las, dimensions: list[str], ring_field: str | None, path: Path) -> tuple[np.ndarray, str]:
    """The laser of every point and where it came from."""
    if ring_field is not None:
        if ring_field not in dimensions:
            raise RecordingError(path, f"no dimension {ring_field!r} (dimensions: {', '.join(dimensions)})",
                                 field=ring_field, expected="the dimension that holds the laser of each point")
        return np.asarray(las[ring_field]).astype(np.int64), f"laser of each point: {ring_field} (as asked)"
    extra = [d for d in RING_DIMENSIONS if d in dimensions]
    if extra:
        return np.asarray(las[extra[0]]).astype(np.int64), f"laser of each point: the extra dimension {extra[0]}"
    source = np.asarray(las.point_source_id).astype(np.int64)
    if len(np.unique(source)) > 1:
        return source, ("laser of each point: point_source_id (it usually holds the flight line: check that the "
                        "producer wrote the laser there)")
    return np.zeros(len(source), dtype=np.int64), "no laser field: one beam (a line scanner)"


def _mounting(p_body: np.ndarray, ring: np.ndarray, lever_arm_m: tuple, boresight_deg: tuple | None
              ) -> tuple[Extrinsic, str]:
    """The lidar -> body extrinsic: as given, or for a single beam without a boresight, the scan plane's axis."""
    if boresight_deg is not None or len(np.unique(ring)) > 1:
        extrinsic = Extrinsic(lever_arm_m, tuple(float(v) for v in boresight_deg or (0.0, 0.0, 0.0)))
        return extrinsic, (f"lidar -> body extrinsic: lever arm {lever_arm_m} m, boresight {extrinsic.boresight_deg} "
                           "deg, as given (it must be the one the cloud was made with)")
    p_body = p_body - np.asarray(lever_arm_m)
    axis = np.linalg.svd(p_body, full_matrices=False)[2][2]  # normal of the scan plane through the body origin
    mean = np.mean(p_body, axis=0)
    forward = -(mean - axis * (mean @ axis))  # x away from the returns: they lie around azimuth 180 deg
    forward /= np.linalg.norm(forward)
    matrix = np.column_stack([forward, np.cross(axis, forward), axis])
    boresight = rpy_deg_from_rotation(Rotation.from_matrix(matrix))
    spread = np.abs(p_body @ axis)
    return (Extrinsic(lever_arm_m, tuple(float(v) for v in boresight)),
            f"lidar -> body boresight FITTED: the scanner's axis is the normal of the plane its returns lie in "
            f"(body frame, through the lever arm {lever_arm_m} m; returns within {np.median(spread):.3f} m of it, median), "
            f"roll, pitch, yaw {', '.join(f'{v:.3f}' for v in boresight)} deg")


def _rotation_hz(p_lidar: np.ndarray, time: np.ndarray) -> float:
    """Turns per second: the median azimuth rate between consecutive returns (by time) / 2 pi."""
    azimuth = np.arctan2(-p_lidar[:, 1], p_lidar[:, 0])
    dt = np.diff(time)
    step = np.abs(np.angle(np.exp(1j * np.diff(azimuth))))
    rate = step[dt > 0] / dt[dt > 0]
    return float(np.median(rate) / (2 * np.pi)) if len(rate) and np.median(rate) > 0 else 10.0


def _limits(n_fibres: int) -> list[str]:
    """What a calibration cannot get from a cloud that was already georeferenced, in plain words."""
    limits = [("LAS points are already georeferenced: the raw range and azimuth are recovered by undoing the "
               "trajectory and the mounting given, so they are only as right as those; a calibration of this "
               "recording finds corrections to the producer's processing, not the sensor's factory values"),
              ("the map projection's scale factor is not removed: ranges along the ground carry it (up to 4 parts "
               "in 10 000 in a UTM zone)")]
    if n_fibres == 1:
        limits.append("one beam: no per-fibre offsets can be estimated (the only fibre is the reference); the "
                      "lever arm, boresight and trajectory corrections remain")
    return limits
