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

The file is read in chunks (laspy's chunk_iterator), twice: a first pass finds the time span,
whether point_source_id varies, and the points the mounting, the model and the spin rate are
fitted on (every n-th point of the file, about FIT_POINTS of them, and its first FIT_POINTS);
the second recovers the raw values chunk by chunk and writes them as they come (return_stream).
Memory holds two chunks and the fit's points, whatever the file's size; the points must be in
time order to within one chunk (a file sorted otherwise, by tile or flight line, is refused).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import laspy
import numpy as np
from scipy.spatial.transform import Rotation

from graphcal.common.atomic import atomic_directory
from graphcal.common.errors import RecordingError
from graphcal.importers.beam_fit import RingModel, misfit_note, ring_model
from graphcal.importers.gpstime import WEEK_S
from graphcal.importers.return_stream import POINTS, ReturnWriter, return_writer, save_imported
from graphcal.importers.velodyne_calibration import VelodyneCalibration
from graphcal.recording.directory import Recording
from graphcal.recording.extrinsic import Extrinsic
from graphcal.recording.geodesy import to_world
from graphcal.recording.points import PointTable, concatenated_columns
from graphcal.recording.poses import PoseTrack
from graphcal.recording.rotations import rpy_deg_from_rotation
from graphcal.recording.trajectory import Trajectory

RING_DIMENSIONS = ("ring", "channel", "laser_id", "laser")
CHUNK_POINTS = 1_000_000  # points read at a time
FIT_POINTS = 400_000  # points the mounting, the model and the spin rate are fitted on
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


@dataclass(frozen=True)
class _Survey:
    """The first pass over the file: its point count, GPS time span (as stored), whether the laser dimension
    takes one value only, and the points the mounting, the model and the spin rate are fitted on: every step-th
    point of the file (sample, about FIT_POINTS) and its first FIT_POINTS points (head), as _columns gives them."""

    n_points: int
    gps_min: float
    gps_max: float
    one_laser: bool
    sample: dict[str, np.ndarray]
    head: dict[str, np.ndarray]


@dataclass(frozen=True)
class _WeekTime:
    """LAS GPS time -> GPS seconds of week: as stored (GPS week time, week_start_s None) or adjusted standard GPS
    time + 1e9 - the start of the first point's week [s since the GPS epoch]."""

    week_start_s: float | None
    note: str

    def seconds(self, gps_time: np.ndarray) -> np.ndarray:
        return gps_time if self.week_start_s is None else (gps_time + _ADJUSTED_OFFSET_S) - self.week_start_s


@dataclass(frozen=True)
class _Reading:
    """How the file's points become returns: the laser dimension (None: a single beam, laser 0), the GPS time
    conversion, and the trajectory's span [GPS s of week] the points are kept within."""

    laser: str | None
    week_time: _WeekTime
    span_s: tuple[float, float]

    def kept(self, columns: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """The points (as _columns gives them) within the span, with their time [GPS s of week] and laser."""
        time = self.week_time.seconds(columns["gps_time"])
        inside = (time >= self.span_s[0]) & (time <= self.span_s[1])
        ring = columns["ring"] if self.laser is not None else np.zeros(len(time), dtype=np.int64)
        return {**{key: values[inside] for key, values in columns.items()}, "time": time[inside],
                "ring": ring[inside]}


def import_las(path: str | Path, trajectory: Trajectory, out: str | Path, *, crs: str | None = None,
               lever_arm_m: tuple[float, float, float] = (0.0, 0.0, 0.0),
               boresight_deg: tuple[float, float, float] | None = None,
               calibration: VelodyneCalibration | None = None, ring_field: str | None = None,
               name: str | None = None, chunk_points: int = CHUNK_POINTS) -> Recording:
    """A LAS/LAZ file and its trajectory (GPS seconds of week) as the recording folder `out` (written whole; an
    existing folder is replaced); see the module docstring. lever_arm_m, boresight_deg: the lidar -> body mounting
    the cloud was made with (boresight None: identity, or fitted for a single beam). The file is read twice,
    chunk_points points at a time: memory holds two chunks and the points of the fit (2 x FIT_POINTS)."""
    path, out = Path(path), Path(out)
    header = _header(path)
    dimensions = list(header.point_format.dimension_names)
    if "gps_time" not in dimensions:
        raise RecordingError(path, f"point format {header.point_format.id} has no GPS time", field="gps_time",
                             expected="a point format with gps_time (1, 3, 4, 5, 6 and above)")
    crs = crs or las_crs(header, path)
    if crs is None:
        raise RecordingError(path, "no CRS in the header", field="crs",
                             expected="a WKT or GeoTIFF CRS in the file, or --crs (e.g. EPSG:32611)")
    laser, laser_note = _laser_dimension(dimensions, ring_field, path)
    survey = _survey(path, laser, header.point_count, chunk_points)
    if laser == "point_source_id" and survey.one_laser:
        laser, laser_note = None, "no laser field: one beam (a line scanner)"
    reading = _Reading(laser, _week_time(header, survey.gps_min), (trajectory.time[0], trajectory.time[-1]))
    sample = _by_time(reading.kept(survey.sample))
    if not len(sample["time"]):
        first, last = reading.week_time.seconds(np.array([survey.gps_min, survey.gps_max]))
        raise RecordingError(path, f"GPS times [{first:.3f}, {last:.3f}] s of week outside the trajectory's "
                                   f"[{reading.span_s[0]:.3f}, {reading.span_s[1]:.3f}]",
                             field="gps_time", expected="the trajectory the cloud was made with")
    poses = to_world(trajectory, crs, path).poses
    p_body = _p_body(sample, poses)
    extrinsic, mount_note = _mounting(p_body, sample["ring"], tuple(float(v) for v in lever_arm_m), boresight_deg)
    head = _by_time(reading.kept(survey.head))
    rotation_hz = _rotation_hz(_p_lidar(_p_body(head, poses), extrinsic), head["time"])
    model = ring_model(_p_lidar(p_body, extrinsic), sample["ring"], "LAS", rotation_hz, path, calibration)
    with atomic_directory(out) as folder:
        returns = _write_returns(folder, path, chunk_points, reading, poses, extrinsic, model)
        notes = [f"{survey.n_points} points of {path.name} (LAS {header.version}, point format "
                 f"{header.point_format.id}), CRS {crs if crs.startswith('EPSG') else 'from the header (WKT)'}",
                 reading.week_time.note, laser_note,
                 f"{survey.n_points - returns.n_returns} points outside the trajectory's time span left out",
                 mount_note, *model.notes, misfit_note(returns.misfit), returns.intensity.note,
                 *_limits(model.sensor.n_fibres)]
        source = {"importer": "las", "file": path.name, "model": "LAS", "time_base": "GPS seconds of week",
                  "notes": notes}
        recording = Recording(name=name or path.stem, crs=crs, sensor=model.sensor, extrinsic=extrinsic,
                              trajectory=trajectory, points=PointTable.open(folder / POINTS), source=source)
        save_imported(recording, folder, path)
    return Recording.load(out, validate=False)


def _write_returns(folder: Path, path: Path, chunk_points: int, reading: _Reading, poses: PoseTrack,
                   extrinsic: Extrinsic, model: RingModel) -> ReturnWriter:
    """The second pass: the raw values of every kept point, chunk by chunk, into folder/points.parquet; the writer
    closed, with what the notes say of them."""
    columns = ["time", "fibre", "range", "azimuth", "intensity"]
    with return_writer(folder, path, _order(chunk_points), columns) as returns:
        for chunk in _chunks(path, chunk_points):
            kept = reading.kept(_columns(chunk, reading.laser))
            _check_lasers(kept["ring"], model, path)
            fibre, range_m, azimuth, misfit = model.raw(kept["ring"], _p_lidar(_p_body(kept, poses), extrinsic))
            returns.add({"time": kept["time"], "fibre": fibre, "range": range_m, "azimuth": azimuth,
                         "intensity": kept["intensity"]}, misfit)
    return returns


def _header(path: Path):
    """The file's LAS header (laspy); RecordingError for a file that is not there or laspy cannot read."""
    if not path.is_file():
        raise RecordingError(path, "file not found")
    with _readable(path), laspy.open(path) as reader:
        return reader.header


def _chunks(path: Path, chunk_points: int) -> Iterator:
    """The file's points, chunk_points at a time (laspy's chunk iterator)."""
    with _readable(path), laspy.open(path) as reader:
        yield from reader.chunk_iterator(chunk_points)


@contextmanager
def _readable(path: Path) -> Iterator[None]:
    """Reading the file: laspy's own errors (not a LAS file, a cut one, LAZ without a backend) as RecordingError."""
    try:
        yield
    except Exception as error:
        raise RecordingError(path, f"not a readable LAS/LAZ file: {type(error).__name__}: {error}",
                             expected="a LAS or LAZ file (LAZ needs lazrs)") from None


def _laser_dimension(dimensions: list[str], ring_field: str | None, path: Path) -> tuple[str, str]:
    """The dimension that holds each point's laser, and a note: ring_field, else the first of RING_DIMENSIONS,
    else point_source_id (a single beam when it takes one value only: see import_las)."""
    if ring_field is not None:
        if ring_field not in dimensions:
            raise RecordingError(path, f"no dimension {ring_field!r} (dimensions: {', '.join(dimensions)})",
                                 field=ring_field, expected="the dimension that holds the laser of each point")
        return ring_field, f"laser of each point: {ring_field} (as asked)"
    extra = [d for d in RING_DIMENSIONS if d in dimensions]
    if extra:
        return extra[0], f"laser of each point: the extra dimension {extra[0]}"
    return "point_source_id", ("laser of each point: point_source_id (it usually holds the flight line: check that "
                               "the producer wrote the laser there)")


def _columns(points, laser: str | None) -> dict[str, np.ndarray]:
    """A chunk of points: world position x, y, z [m, the file's CRS], gps_time and intensity as stored, and the
    laser (ring) from the dimension `laser` (0 for all when None)."""
    return {"x": np.asarray(points.x), "y": np.asarray(points.y), "z": np.asarray(points.z),
            "gps_time": np.asarray(points.gps_time, dtype=np.float64),
            "intensity": np.asarray(points.intensity, dtype=np.float64),
            "ring": (np.asarray(points[laser]).astype(np.int64) if laser is not None
                     else np.zeros(len(points), dtype=np.int64))}


def _survey(path: Path, laser: str, n_declared: int, chunk_points: int) -> _Survey:
    """The first pass (see _Survey); the sample takes every (n_declared // FIT_POINTS)-th point of the file."""
    step = max(1, n_declared // FIT_POINTS)
    samples, heads = [], []
    n, gps, lasers = 0, (np.inf, -np.inf), (np.inf, -np.inf)
    for chunk in _chunks(path, chunk_points):
        columns = _columns(chunk, laser)
        samples.append({key: values[(-n) % step::step].copy() for key, values in columns.items()})  # not views
        if n < FIT_POINTS:
            heads.append({key: values[:FIT_POINTS - n].copy() for key, values in columns.items()})
        n += len(columns["gps_time"])
        gps = (min(gps[0], float(columns["gps_time"].min())), max(gps[1], float(columns["gps_time"].max())))
        lasers = (min(lasers[0], int(columns["ring"].min())), max(lasers[1], int(columns["ring"].max())))
    if not n:
        raise RecordingError(path, "no point", expected="a LAS file with points")
    return _Survey(n, gps[0], gps[1], lasers[0] == lasers[1], concatenated_columns(samples),
                   concatenated_columns(heads))


def _week_time(header, gps_min: float) -> _WeekTime:
    """How the file's GPS times become GPS seconds of week (of the first point's week for adjusted standard time)."""
    if not int(header.global_encoding.value) & 1:
        return _WeekTime(None, "gps_time read as GPS seconds of week (the header's GPS week time flag)")
    week = int(np.floor((gps_min + _ADJUSTED_OFFSET_S) / WEEK_S))
    return _WeekTime(week * WEEK_S, f"gps_time read as adjusted standard GPS time, turned into seconds of week {week}")


def _by_time(columns: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    order = np.argsort(columns["time"], kind="stable")
    return {key: values[order] for key, values in columns.items()}


def _p_body(columns: dict[str, np.ndarray], poses: PoseTrack) -> np.ndarray:
    """p_body = R_world_body(t)^T (p_world - t_world_body(t)) (N, 3) [m] of every point at its own time."""
    position, rotation = poses.interpolate(columns["time"])
    world = np.column_stack([columns["x"], columns["y"], columns["z"]])
    return rotation.inv().apply(world - position)


def _p_lidar(p_body: np.ndarray, extrinsic: Extrinsic) -> np.ndarray:
    """p_lidar = R_body_lidar^T (p_body - t_body_lidar) (N, 3) [m]."""
    return extrinsic.rotation.inv().apply(p_body - np.asarray(extrinsic.lever_arm_m))


def _check_lasers(ring: np.ndarray, model: RingModel, path: Path) -> None:
    """RecordingError when a point's laser is none of those the model was fitted with."""
    unknown = model.unknown_ring(ring)
    if unknown is not None:
        raise RecordingError(path, f"laser {unknown} absent from the points the model was fitted on (every "
                                   f"{FIT_POINTS:,}-th of the file)", field="ring",
                             expected="lasers with returns throughout the file")


def _order(chunk_points: int) -> str:
    return (f"points in time order to within {chunk_points:,} points (sort the file by GPS time first, e.g. "
            "lassort -gps_time or PDAL's filters.sort on GpsTime)")


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
