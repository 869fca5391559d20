"""KITTI raw drive (HDL-64E velodyne_points + OXTS) -> a recording (graphcal-recording/1).

KITTI ships corrected Cartesian points (float32 x, y, z, reflectance; x forward, y left, z up),
not raw packets, and no per-return time. What the importer recovers, and how:

- range = |p|, encoder azimuth = atan2(-y, x) wrapped to [0, 2 pi) (clockwise, x at 0);
- fibre: each fibre's beam is a line in the vertical plane of the return, z cos e - h sin e = V
  (h = hypot(x, y); elevation e, vertical offset V: the HDL-64E factory terms). Every return goes
  to the nearest line; the lines start at the nominal HDL-64E values (graphcal's catalogue or a
  calibration file) and are refitted (total least squares) on the first scans, 3 rounds.
  sensor.yaml holds the fitted elevations and vertical offsets (no azimuth, range or horizontal
  offsets: KITTI's points cannot show them);
- range, encoder azimuth: the model's inverse (`SensorModel.from_xyz`) for that fibre: the range
  along the beam (|p| when V = 0) and atan2(-y, x) wrapped to [0, 2 pi) (clockwise, x at 0); the
  distance of the point from its fibre's line is the model misfit the import reports;
- time: KITTI has none per return. It is DERIVED from the azimuth: the head turns clockwise from
  the back (azimuth pi, scan start) through the front (0, middle) to the back again (scan end),
  so t = t_start + (t_end - t_start) * ((azimuth - pi) mod 2 pi) / 2 pi with the scan's
  timestamps_start/end.txt;
- trajectory: OXTS lat, lon, alt, roll, pitch, yaw (yaw 0 = east, counter-clockwise: already the
  recording's ENU convention); returns outside the OXTS time span are left out (no extrapolation);
- extrinsic: calib_imu_to_velo.txt (p_velo = R p_imu + T) inverted to lidar -> body (IMU).
Timestamps are read as UTC and converted to GPS seconds of week. The scans are read and their returns written one
at a time (return_stream, points.parquet sorted by time), in memory bounded whatever the drive's length.
"""

from __future__ import annotations

import calendar
import time as _time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from graphcal.common.errors import RecordingError
from graphcal.recording.extrinsic import Extrinsic
from graphcal.importers.beam_fit import fit_beam_line, misfit_note
from graphcal.importers.gpstime import seconds_of_week
from graphcal.importers.return_stream import ReturnWriter, write_import
from graphcal.importers.velodyne_calibration import VelodyneCalibration
from graphcal.recording.points import PointTable
from graphcal.common.progress import progress
from graphcal.recording.directory import Recording
from graphcal.recording.rotations import rpy_deg_from_rotation, unwrap_deg
from graphcal.recording.sensor import SensorModel, sensor_from_catalog
from graphcal.recording.trajectory import Trajectory

_REFINE_SCANS = 5
_ORDER = "scans in time order (timestamps_start.txt increasing), each one's returns between its start and end"
_OXTS_FIELDS = 30


def read_timestamps(path: Path) -> tuple[float, np.ndarray]:
    """KITTI timestamp file ('YYYY-MM-DD HH:MM:SS.fffffffff' per line, UTC) -> (UTC midnight of the
    first day [s since 1970], seconds since it per line)."""
    if not path.is_file():
        raise RecordingError(path, "file not found")
    lines = [line.strip() for line in path.read_text().splitlines() if line.strip()]
    seconds = []
    for row, line in enumerate(lines, start=1):
        try:
            whole, _, fraction = line.partition(".")
            stamp = calendar.timegm(_time.strptime(whole, "%Y-%m-%d %H:%M:%S"))
            seconds.append((stamp, float("0." + fraction) if fraction else 0.0))
        except ValueError:
            raise RecordingError(path, f"timestamp {line!r}", row=row, expected="YYYY-MM-DD HH:MM:SS.fffffffff") from None
    if not seconds:
        raise RecordingError(path, "no timestamps", expected="one timestamp per line")
    midnight = seconds[0][0] - seconds[0][0] % 86400
    return float(midnight), np.array([whole - midnight + fraction for whole, fraction in seconds])


def read_imu_to_velo(path: Path) -> Extrinsic:
    """calib_imu_to_velo.txt (R: 9 values, T: 3 values; p_velo = R p_imu + T) -> lidar -> body (IMU) extrinsic."""
    values = {}
    for line in path.read_text().splitlines() if path.is_file() else []:
        key, _, rest = line.partition(":")
        if key in ("R", "T"):
            try:
                values[key] = np.array([float(v) for v in rest.split()])
            except ValueError:
                raise RecordingError(path, f"line {line!r}", field=key, expected="numbers") from None
    if values.get("R", np.array([])).shape != (9,) or values.get("T", np.array([])).shape != (3,):
        raise RecordingError(path, "no 'R:' (9 numbers) and 'T:' (3 numbers) lines" if path.is_file() else "file not found",
                             expected="KITTI calib_imu_to_velo.txt")
    rotation = values["R"].reshape(3, 3)
    return Extrinsic(lever_arm_m=tuple(float(v) for v in -rotation.T @ values["T"]),
                     boresight_deg=tuple(float(v) for v in rpy_deg_from_rotation(Rotation.from_matrix(rotation.T))))


def read_scan(path: Path) -> np.ndarray:
    """One velodyne_points .bin -> (N, 4) float32 x, y, z [m], reflectance [0, 1]."""
    size = path.stat().st_size if path.is_file() else -1
    if size < 0 or size % 16:
        raise RecordingError(path, "file not found" if size < 0 else f"{size} bytes",
                             expected="float32 x, y, z, reflectance records (a multiple of 16 bytes)")
    return np.fromfile(path, dtype="<f4").reshape(-1, 4)


def assign_fibres(h_m: np.ndarray, z_m: np.ndarray, elevation_deg: np.ndarray, vertical_m: np.ndarray,
                  chunk: int = 100_000) -> np.ndarray:
    """Fibre of the nearest beam line z cos e - h sin e = V for points (h, z) of their vertical plane."""
    e = np.radians(elevation_deg)[None, :]
    fibre = np.empty(len(h_m), dtype=np.int16)
    for s in range(0, len(h_m), chunk):
        residual = z_m[s:s + chunk, None] * np.cos(e) - h_m[s:s + chunk, None] * np.sin(e) - vertical_m[None, :]
        fibre[s:s + chunk] = np.argmin(np.abs(residual), axis=1)
    return fibre


def fit_fibres(h_m: np.ndarray, z_m: np.ndarray, elevation_deg: np.ndarray, vertical_m: np.ndarray,
               rounds: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Refit each fibre's beam line (elevation deg, vertical offset m) to the points it gets, by
    total least squares without its outliers (> 5 median residuals), alternating with the assignment."""
    elevation_deg, vertical_m = elevation_deg.copy(), vertical_m.copy()
    for _ in range(rounds):
        fibre = assign_fibres(h_m, z_m, elevation_deg, vertical_m)
        for k in range(len(elevation_deg)):
            mine = fibre == k
            if mine.sum() < 3:
                continue
            elevation_deg[k], vertical_m[k] = fit_beam_line(h_m[mine], z_m[mine], elevation_deg[k], vertical_m[k])
    return elevation_deg, vertical_m


def import_kitti(drive: str | Path, out: str | Path, calibration: VelodyneCalibration | None = None,
                 name: str | None = None, chunk_scans: int = 1, quiet: bool = False) -> Recording:
    """A KITTI raw drive folder (…_drive_NNNN_sync or _extract) as the recording folder `out` (written whole or not
    at all; an existing folder is replaced), chunk_scans scans read and written at a time (memory holds them and
    their returns, whatever the drive's length); see the module docstring."""
    drive = Path(drive)
    velodyne, oxts = drive / "velodyne_points", drive / "oxts"
    scans = sorted((velodyne / "data").glob("*.bin"))
    if not scans:
        raise RecordingError(velodyne / "data", "no .bin scans", expected="KITTI velodyne_points/data/*.bin")
    midnight, start = read_timestamps(velodyne / "timestamps_start.txt")
    end = _seconds_since(velodyne / "timestamps_end.txt", midnight)
    for label, stamps in (("timestamps_start.txt", start), ("timestamps_end.txt", end)):
        if len(stamps) != len(scans):
            raise RecordingError(velodyne / label, f"{len(stamps)} timestamps for {len(scans)} scans",
                                 expected="one timestamp per scan")
    base = calibration.sensor if calibration is not None else sensor_from_catalog("HDL-64E")
    first = np.vstack([read_scan(path)[:, :3].astype(np.float64) for path in scans[:_REFINE_SCANS]])
    elevation_deg, vertical_m = fit_fibres(np.hypot(first[:, 0], first[:, 1]), first[:, 2], base.elevation_deg,
                                           base.vertical_offset_m)
    zeros = np.zeros(len(elevation_deg))
    sensor = SensorModel(model="HDL-64E", rotation_hz=float(1.0 / np.median(end - start)),
                         reference_fibre=int(np.argmin(np.abs(elevation_deg))), elevation_deg=elevation_deg,
                         azimuth_offset_deg=zeros, range_offset_m=zeros, vertical_offset_m=vertical_m,
                         horizontal_offset_m=zeros, height_offset_m=zeros, timing=base.timing)
    trajectory, oxts_span = _oxts_trajectory(oxts, midnight)
    extrinsic = read_imu_to_velo(_find_calibration(drive))
    kept = {"left_out": 0, "week": None}

    def chunks() -> Iterator[tuple[dict[str, np.ndarray], np.ndarray]]:
        indexed, step = list(enumerate(scans)), max(1, chunk_scans)
        groups = [indexed[s:s + step] for s in range(0, len(indexed), step)]
        for group in progress(groups, f"reading {drive.name}", quiet=quiet):
            columns, misfit = _scan_returns(group, start, end, sensor)
            inside = (columns["time"] >= oxts_span[0]) & (columns["time"] <= oxts_span[1])
            kept["left_out"] += int(np.count_nonzero(~inside))
            if inside.any():
                # sorted by the time since midnight first: the returns that GPS seconds of week (coarser float64
                # steps) make simultaneous keep that order
                kept_rows = np.flatnonzero(inside)[np.argsort(columns["time"][inside], kind="stable")]
                columns, misfit = {key: values[kept_rows] for key, values in columns.items()}, misfit[kept_rows]
                columns["time"], kept["week"] = seconds_of_week(midnight, columns["time"], kept["week"])
                yield columns, misfit

    def finish(returns: ReturnWriter, points: PointTable) -> Recording:
        if not returns.n_returns:
            raise RecordingError(oxts / "timestamps.txt", "no return within the OXTS time span",
                                 expected="OXTS poses over the time of the scans")
        week = kept["week"]
        trajectory_time, _ = seconds_of_week(midnight, trajectory.time, week)
        model_source = "the calibration" if calibration else "the HDL-64E catalogue"
        notes = [f"{len(scans)} KITTI scans, {returns.n_returns} returns kept",
                 ("per-return time DERIVED from the azimuth (KITTI has none): t = start + (end - start) * "
                  "((azimuth - pi) mod 2 pi) / 2 pi, with timestamps_start/end.txt"),
                 ("the driver's per-laser corrections are already in KITTI's points: raw values are recovered with a "
                  "fitted nominal model (no azimuth, range or horizontal offsets)"),
                 (f"fibre = nearest beam line (elevation, vertical offset) starting from {model_source}, refitted on "
                  f"the first {min(len(scans), _REFINE_SCANS)} scans; range and azimuth from the model's inverse"),
                 misfit_note(returns.misfit),
                 f"{kept['left_out']} returns outside the OXTS time span left out",
                 f"times are GPS seconds of week {week} (KITTI timestamps read as UTC)",
                 "OXTS altitude used as the height, as recorded (KITTI documents it as altitude, not ellipsoidal "
                 "height)"]
        source = {"importer": "kitti-raw", "file": drive.name, "model": "HDL-64E",
                  "time_base": "GPS seconds of week", "gps_week": week, "notes": notes}
        return Recording(name=name or drive.name, crs="auto", sensor=sensor, extrinsic=extrinsic,
                         trajectory=Trajectory(trajectory_time, trajectory.position, trajectory.rpy_deg,
                                               geodetic=True), points=points, source=source)

    return write_import(Path(out), drive, _ORDER, chunks(), finish)


def _scan_returns(scans: list[tuple[int, Path]], start: np.ndarray, end: np.ndarray, sensor: SensorModel
                  ) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """The returns of some scans (index, .bin file): time (s since the drive's UTC midnight, derived from the
    azimuth), fibre, range [m], azimuth [rad], intensity (reflectance x 255), scan (its index); and each one's model
    misfit [m] (its distance from its fibre's beam line). The empty points (0, 0, 0) are left out."""
    columns = {key: [] for key in ("time", "fibre", "range", "azimuth", "intensity", "scan")}
    misfit = []
    for index, path in scans:
        raw = read_scan(path)
        keep = np.any(raw[:, :3] != 0, axis=1)
        xyz, reflectance = raw[keep, :3].astype(np.float64), raw[keep, 3]
        fibre = assign_fibres(np.hypot(xyz[:, 0], xyz[:, 1]), xyz[:, 2], sensor.elevation_deg,
                              sensor.vertical_offset_m)
        range_m, azimuth, off_line = sensor.from_xyz(fibre, xyz)
        misfit.append(np.abs(off_line))
        fraction = np.mod(azimuth - np.pi, 2 * np.pi) / (2 * np.pi)
        columns["time"].append(start[index] + (end[index] - start[index]) * fraction)
        columns["fibre"].append(fibre)
        columns["range"].append(range_m)
        columns["azimuth"].append(azimuth)
        columns["intensity"].append(np.clip(reflectance * 255.0, 0.0, 255.0))
        columns["scan"].append(np.full(len(range_m), index))
    return {key: np.concatenate(values) for key, values in columns.items()}, np.concatenate(misfit)


def _seconds_since(path: Path, midnight: float) -> np.ndarray:
    """A timestamp file as seconds since `midnight` (UTC, s since 1970)."""
    own_midnight, seconds = read_timestamps(path)
    return seconds + (own_midnight - midnight)


def _oxts_trajectory(oxts: Path, midnight: float) -> tuple[Trajectory, tuple[float, float]]:
    stamps = _seconds_since(oxts / "timestamps.txt", midnight)
    files = sorted((oxts / "data").glob("*.txt"))
    if len(files) != len(stamps):
        raise RecordingError(oxts / "timestamps.txt", f"{len(stamps)} timestamps for {len(files)} OXTS files",
                             expected="one timestamp per oxts/data file")
    rows = []
    for path in files:
        values = path.read_text().split()
        try:
            row = [float(v) for v in values]
        except ValueError:
            row = []
        if len(row) != _OXTS_FIELDS or not np.all(np.isfinite(row[:6])):
            raise RecordingError(path, f"{len(values)} fields", expected=f"{_OXTS_FIELDS} numbers (KITTI OXTS packet)")
        rows.append(row[:6])
    values = np.array(rows)
    rpy = np.column_stack([np.degrees(values[:, 3]), np.degrees(values[:, 4]), unwrap_deg(np.degrees(values[:, 5]))])
    trajectory = Trajectory(stamps, values[:, :3], rpy, geodetic=True)
    trajectory.validate(oxts / "timestamps.txt")
    return trajectory, (float(stamps[0]), float(stamps[-1]))


def _find_calibration(drive: Path) -> Path:
    """calib_imu_to_velo.txt next to the drive (KITTI's date folder) or inside it."""
    for folder in (drive, drive.parent):
        if (folder / "calib_imu_to_velo.txt").is_file():
            return folder / "calib_imu_to_velo.txt"
    return drive.parent / "calib_imu_to_velo.txt"
