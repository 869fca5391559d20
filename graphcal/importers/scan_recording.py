"""Scans of corrected sensor-frame points with ring and time (PointCloud2, PCD) -> a recording.

The nominal model comes from beam_fit (a calibration file, or per-ring lines fitted to the
first scans); every return's raw range and encoder azimuth come from its inverse. Times are
turned from UTC (s since 1970) into GPS seconds of week, the time base of every importer, and
returns outside the trajectory's span are left out (no extrapolation).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from graphcal.common.errors import RecordingError
from graphcal.common.progress import progress
from graphcal.importers.beam_fit import misfit_note, ring_model
from graphcal.importers.gpstime import seconds_of_week
from graphcal.importers.point_fields import ScanPoints, intensity_0_255
from graphcal.importers.velodyne_calibration import VelodyneCalibration
from graphcal.recording.directory import Recording
from graphcal.recording.extrinsic import Extrinsic
from graphcal.recording.points import PointTable
from graphcal.recording.trajectory import Trajectory

FIT_SCANS = 5
FIT_POINTS = 400_000


@dataclass
class ScanSource:
    """Where the scans come from and what goes with them.

    path: the bag, folder or file read; importer: its name in recording.yaml; model: the sensor's
    name in sensor.yaml; trajectory: body -> world poses, times in UTC s since 1970 (trajectory_utc)
    or already GPS seconds of week; crs: the recording's world CRS; notes: what the reader assumed."""

    path: Path
    importer: str
    model: str
    trajectory: Trajectory
    trajectory_utc: bool
    extrinsic: Extrinsic
    crs: str = "auto"
    notes: list[str] = field(default_factory=list)


def recording_from_scans(scans: list[ScanPoints], source: ScanSource, calibration: VelodyneCalibration | None = None,
                         name: str | None = None, quiet: bool = False) -> Recording:
    """The scans (in time order) as a recording; see the module docstring."""
    scans = [scan for scan in scans if len(scan.time_s)]
    if not scans:
        raise RecordingError(source.path, "no return in the scans", expected="points with x, y, z, ring and time")
    rotation_hz = _rotation_hz(scans)
    fit = _fit_sample(scans[:FIT_SCANS])
    model = ring_model(fit.xyz, fit.ring, source.model, rotation_hz, source.path, calibration)
    columns = {key: [] for key in ("time", "fibre", "range", "azimuth", "intensity", "scan")}
    misfit = []
    for index, scan in enumerate(progress(scans, f"recovering raw returns of {source.path.name}", quiet=quiet)):
        unknown = (scan.ring >= len(model.fibre_of_ring)) | (model.fibre_of_ring[np.minimum(
            scan.ring, len(model.fibre_of_ring) - 1)] < 0)
        if unknown.any():
            raise RecordingError(source.path, f"scan {index}: ring {int(scan.ring[unknown][0])} absent from the first "
                                              f"{FIT_SCANS} scans the model was fitted on", field="ring",
                                 expected="the same lasers in every scan")
        fibre, range_m, azimuth, off_line = model.raw(scan.ring, scan.xyz)
        misfit.append(off_line)
        columns["time"].append(scan.time_s)
        columns["fibre"].append(fibre)
        columns["range"].append(range_m)
        columns["azimuth"].append(azimuth)
        columns["intensity"].append(scan.intensity)
        columns["scan"].append(np.full(len(range_m), index))
    arrays = {key: np.concatenate(values) for key, values in columns.items()}
    arrays["intensity"], intensity_note = intensity_0_255(arrays["intensity"])
    order = np.argsort(arrays["time"], kind="stable")
    arrays = {key: values[order] for key, values in arrays.items()}
    base = float(np.floor(arrays["time"][0]))
    time, week = seconds_of_week(base, arrays.pop("time") - base)
    trajectory = source.trajectory
    if source.trajectory_utc:
        trajectory_time, _ = seconds_of_week(base, trajectory.time - base, week)
        trajectory = Trajectory(trajectory_time, trajectory.position, trajectory.rpy_deg, trajectory.geodetic)
    inside = (time >= trajectory.time[0]) & (time <= trajectory.time[-1])
    if not inside.any():
        raise RecordingError(source.path, f"returns over [{time[0]:.3f}, {time[-1]:.3f}] GPS s of week {week}, poses "
                                          f"over [{trajectory.time[0]:.3f}, {trajectory.time[-1]:.3f}]",
                             expected="a trajectory over the time of the scans (same clock)")
    arrays = {key: values[inside] for key, values in arrays.items()}
    times = [scan.time_s for scan in scans]
    notes = [f"{len(scans)} scans, {int(inside.sum())} returns kept, {model.sensor.n_fibres} fibres, "
             f"{rotation_hz:.3f} Hz (from the scans' spacing)",
             *sorted({scan.time_note for scan in scans}), *source.notes, *model.notes,
             misfit_note(np.concatenate(misfit)), intensity_note,
             f"{int((~inside).sum())} returns outside the trajectory's time span left out",
             f"times are GPS seconds of week {week} (UTC stamps + leap seconds); scans span "
             f"{min(t.min() for t in times):.3f} .. {max(t.max() for t in times):.3f} s since 1970"]
    recording_source = {"importer": source.importer, "file": source.path.name, "model": source.model,
                        "time_base": "GPS seconds of week", "gps_week": week, "notes": notes}
    points = PointTable.from_arrays(time=time[inside], **arrays)
    return Recording(name=name or source.path.stem, crs=source.crs, sensor=model.sensor, extrinsic=source.extrinsic,
                     trajectory=trajectory, points=points, source=recording_source)


def local_crs(lat_deg: float = 0.0, lon_deg: float = 0.0) -> str:
    """A local metric frame as a projected CRS: transverse Mercator centred at (lat, lon), scale 1 at the centre."""
    return f"+proj=tmerc +lat_0={lat_deg:.9f} +lon_0={lon_deg:.9f} +k=1 +x_0=0 +y_0=0 +ellps=WGS84 +units=m +no_defs"


def _rotation_hz(scans: list[ScanPoints]) -> float:
    """Spin rate [Hz]: 1 / the median spacing of the scans' first returns (1 / the span of a single scan)."""
    starts = np.array([scan.time_s.min() for scan in scans])
    period = float(np.median(np.diff(starts))) if len(scans) > 1 else float(np.ptp(scans[0].time_s))
    return round(1.0 / period, 3) if period > 0 else 10.0


def _fit_sample(scans: list[ScanPoints]) -> ScanPoints:
    """The returns of the first scans (at most FIT_POINTS, evenly spread) to fit the model on."""
    xyz = np.vstack([scan.xyz for scan in scans])
    ring = np.concatenate([scan.ring for scan in scans])
    step = max(1, len(ring) // FIT_POINTS)
    return ScanPoints(xyz[::step], np.zeros(0), ring[::step], np.zeros(0), "")
