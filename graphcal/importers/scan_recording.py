"""Scans of corrected sensor-frame points with ring and time (PointCloud2, PCD) -> a recording folder.

The nominal model comes from beam_fit (a calibration file, or per-ring lines fitted to the
first scans); every return's raw range and encoder azimuth come from its inverse. Times are
turned from UTC (s since 1970) into GPS seconds of week, the time base of every importer, and
returns outside the trajectory's span are left out (no extrapolation).

The scans are taken one at a time and their returns written as they come (return_stream):
memory holds the first FIT_SCANS scans (for the model), two scans of returns (time order is
restored within that window) and one number per scan (the spin rate is the median spacing of
the scans' first returns).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from itertools import chain, islice
from pathlib import Path

import numpy as np

from graphcal.common.atomic import atomic_directory
from graphcal.common.errors import RecordingError
from graphcal.common.progress import progress
from graphcal.importers.beam_fit import RingModel, misfit_note, ring_model
from graphcal.importers.gpstime import seconds_of_week
from graphcal.importers.point_fields import ScanPoints
from graphcal.importers.return_stream import POINTS, return_writer, save_imported
from graphcal.importers.velodyne_calibration import VelodyneCalibration
from graphcal.recording.directory import Recording
from graphcal.recording.extrinsic import Extrinsic
from graphcal.recording.points import SCHEMA, PointTable
from graphcal.recording.trajectory import Trajectory

FIT_SCANS = 5
FIT_POINTS = 400_000
_ORDER = "scans in time order, each overlapping at most the one before it (sort the messages or files by time)"


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


@dataclass
class _ScanTally:
    """What the notes say of all the scans: their first returns' times [s since 1970 UTC], the span of their
    returns [s since 1970 UTC], how their time fields were read, the returns left out."""

    starts_s: list[float] = field(default_factory=list)
    first_s: float = np.inf
    last_s: float = -np.inf
    time_notes: set[str] = field(default_factory=set)
    left_out: int = 0

    def add(self, scan: ScanPoints, left_out: int) -> None:
        self.starts_s.append(float(scan.time_s.min()))
        self.first_s, self.last_s = min(self.first_s, self.starts_s[-1]), max(self.last_s, float(scan.time_s.max()))
        self.time_notes.add(scan.time_note)
        self.left_out += left_out


def write_scan_recording(scans: Iterable[ScanPoints], source: ScanSource, out: str | Path,
                         calibration: VelodyneCalibration | None = None, name: str | None = None,
                         quiet: bool = False) -> Recording:
    """The scans (in time order, taken one at a time) as the recording folder `out`, written whole or not at all
    (an existing folder is replaced); see the module docstring."""
    out = Path(out)
    scans = (scan for scan in scans if len(scan.time_s))
    head = list(islice(scans, FIT_SCANS))
    if not head:
        raise RecordingError(source.path, "no return in the scans", expected="points with x, y, z, ring and time")
    fit = _fit_sample(head)
    model = ring_model(fit.xyz, fit.ring, source.model, _rotation_hz([s.time_s.min() for s in head], head[0]),
                       source.path, calibration)
    first_s = min(float(scan.time_s.min()) for scan in head)
    base = float(np.floor(first_s))
    _, week = seconds_of_week(base, first_s - base)
    trajectory = _gps_trajectory(source, base, week)
    tally = _ScanTally()
    with atomic_directory(out) as folder:
        with return_writer(folder, source.path, _ORDER, list(SCHEMA)) as returns:
            every_scan = progress(chain(head, scans), f"recovering raw returns of {source.path.name}", quiet=quiet)
            for index, scan in enumerate(every_scan):
                _check_rings(scan, model, index, source.path)
                fibre, range_m, azimuth, misfit = model.raw(scan.ring, scan.xyz)
                time, _ = seconds_of_week(base, scan.time_s - base, week)
                inside = (time >= trajectory.time[0]) & (time <= trajectory.time[-1])
                columns = {"time": time, "fibre": fibre, "range": range_m, "azimuth": azimuth,
                           "intensity": scan.intensity, "scan": np.full(len(time), index)}
                returns.add({key: values[inside] for key, values in columns.items()}, misfit[inside])
                tally.add(scan, int((~inside).sum()))
        if not returns.n_returns:
            span, _ = seconds_of_week(base, np.array([tally.first_s, tally.last_s]) - base, week)
            raise RecordingError(source.path, f"returns over [{span[0]:.3f}, {span[1]:.3f}] GPS s of week {week}, "
                                              f"poses over [{trajectory.time[0]:.3f}, {trajectory.time[-1]:.3f}]",
                                 expected="a trajectory over the time of the scans (same clock)")
        sensor = replace(model.sensor, rotation_hz=_rotation_hz(tally.starts_s, head[0]))
        notes = [f"{len(tally.starts_s)} scans, {returns.n_returns} returns kept, {sensor.n_fibres} fibres, "
                 f"{sensor.rotation_hz:.3f} Hz (from the scans' spacing)",
                 *sorted(tally.time_notes), *source.notes, *model.notes, misfit_note(returns.misfit),
                 returns.intensity.note, f"{tally.left_out} returns outside the trajectory's time span left out",
                 f"times are GPS seconds of week {week} (UTC stamps + leap seconds); scans span "
                 f"{tally.first_s:.3f} .. {tally.last_s:.3f} s since 1970"]
        recording_source = {"importer": source.importer, "file": source.path.name, "model": source.model,
                            "time_base": "GPS seconds of week", "gps_week": week, "notes": notes}
        recording = Recording(name=name or source.path.stem, crs=source.crs, sensor=sensor,
                              extrinsic=source.extrinsic, trajectory=trajectory,
                              points=PointTable.open(folder / POINTS), source=recording_source)
        save_imported(recording, folder, source.path)
    return Recording.load(out, validate=False)


def local_crs(lat_deg: float = 0.0, lon_deg: float = 0.0) -> str:
    """A local metric frame as a projected CRS: transverse Mercator centred at (lat, lon), scale 1 at the centre."""
    return f"+proj=tmerc +lat_0={lat_deg:.9f} +lon_0={lon_deg:.9f} +k=1 +x_0=0 +y_0=0 +ellps=WGS84 +units=m +no_defs"


def _rotation_hz(starts_s: list[float], first: ScanPoints) -> float:
    """Spin rate [Hz]: 1 / the median spacing of the scans' first returns [s] (1 / the span of the first scan when
    there is one)."""
    period = float(np.median(np.diff(starts_s))) if len(starts_s) > 1 else float(np.ptp(first.time_s))
    return round(1.0 / period, 3) if period > 0 else 10.0


def _gps_trajectory(source: ScanSource, base_s: float, week: int) -> Trajectory:
    """The source's trajectory with its times in GPS seconds of `week` (from UTC s since 1970 = base_s + offset)."""
    trajectory = source.trajectory
    if not source.trajectory_utc:
        return trajectory
    time, _ = seconds_of_week(base_s, trajectory.time - base_s, week)
    return Trajectory(time, trajectory.position, trajectory.rpy_deg, trajectory.geodetic)


def _check_rings(scan: ScanPoints, model: RingModel, index: int, path: Path) -> None:
    """RecordingError when the scan has a ring the model was not fitted with."""
    unknown = model.unknown_ring(scan.ring)
    if unknown is not None:
        raise RecordingError(path, f"scan {index}: ring {unknown} absent from the first "
                                   f"{FIT_SCANS} scans the model was fitted on", field="ring",
                             expected="the same lasers in every scan")


def _fit_sample(scans: list[ScanPoints]) -> ScanPoints:
    """The returns of the first scans (at most FIT_POINTS, evenly spread) to fit the model on."""
    xyz = np.vstack([scan.xyz for scan in scans])
    ring = np.concatenate([scan.ring for scan in scans])
    step = max(1, len(ring) // FIT_POINTS)
    return ScanPoints(xyz[::step], np.zeros(0), ring[::step], np.zeros(0), "")
