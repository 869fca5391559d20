"""A folder of per-scan PCD files with ring and per-point time, and a per-frame pose file -> a recording.

What is read: every *.pcd of the folder (name order), with pcd.read_pcd; x, y, z, intensity,
ring and per-point time as point_fields describes. Relative per-point times count from the
stamp in the file name (a number: s since 1970, or ns above 1e15).

The trajectory is the pose file's (frame_poses): each matrix is the pose of the scan's frame
(p_world = R p_frame + t), placed at the scan's last return (`pose_at="end"`, the ROS drivers'
and OpenCalib's stamp) or first (`"start"`). Frames are matched by name (the PCD file's stem)
or, for nameless KITTI files, by order. When the frame names read as times, every pose of the
file gets one: the name's time shifted onto the points' clock by the median offset of the
matched scans (that absorbs a time zone), so poses around the scans are used too.

The pose frame is the recording's world: a projected CRS when the poses are in one (crs=...),
else a local frame, written as a transverse Mercator centred at `origin` (lat, lon deg; default
0, 0), whose scale factor is 1 within 1e-7 over 10 km. Body = the frame the poses are of: the
lidar itself unless an extrinsic is given.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from graphcal.common.errors import RecordingError
from graphcal.common.progress import progress
from graphcal.importers.frame_poses import FramePoses, frame_time, read_frame_poses
from graphcal.importers.pcd import read_pcd
from graphcal.importers.point_fields import ScanPoints, scan_points
from graphcal.importers.scan_recording import ScanSource, local_crs, write_scan_recording
from graphcal.importers.velodyne_calibration import VelodyneCalibration
from graphcal.recording.directory import Recording
from graphcal.recording.extrinsic import Extrinsic
from graphcal.recording.rotations import rpy_deg_from_rotation, unwrap_deg
from graphcal.recording.trajectory import Trajectory

_NAME_CLOCK_SPREAD_S = 0.05  # frame names on one clock: their offsets from the scans agree within this


def import_pcd_folder(folder: str | Path, poses: str | Path, out: str | Path, *,
                      calibration: VelodyneCalibration | None = None,
                      crs: str | None = None, origin: tuple[float, float] = (0.0, 0.0),
                      extrinsic: Extrinsic | None = None, pose_at: str = "end", model: str = "lidar",
                      name: str | None = None, quiet: bool = False) -> Recording:
    """The PCD scans of `folder` with the poses of `poses` as the recording folder `out` (written whole; an existing
    folder is replaced); see the module docstring. The scans are read whole (the poses are timed by them)."""
    folder = Path(folder)
    if pose_at not in ("start", "end"):
        raise ValueError(f"pose_at must be 'start' or 'end', not {pose_at!r}")
    files = sorted(folder.glob("*.pcd")) if folder.is_dir() else []
    if not files:
        raise RecordingError(folder, "no .pcd file" if folder.is_dir() else "folder not found",
                             expected="a folder of per-scan PCD files")
    scans, encodings = [], set()
    for path in progress(files, f"reading {folder.name}", quiet=quiet):
        header, fields = read_pcd(path)
        encodings.add(header.encoding)
        scans.append(scan_points(fields, path, _numeric_stamp(path.stem), "the stamp in the file name"))
    frames = read_frame_poses(poses)
    trajectory, notes = _trajectory(Path(poses), frames, [p.stem for p in files], scans, pose_at)
    notes = [f"{len(files)} PCD files ({', '.join(sorted(encodings))})", *notes,
             "points taken as the driver wrote them, in the sensor frame; raw range and azimuth are recovered through "
             "the nominal model (exact only when it is the driver's own)"]
    extrinsic_note = ("lidar -> body extrinsic as given" if extrinsic is not None else
                      "the poses are the lidar's own: lidar -> body extrinsic identity (lever arm and boresight cannot "
                      "be calibrated from these poses; give the body poses and the extrinsic for that)")
    source = ScanSource(path=folder, importer="pcd", model=model, trajectory=trajectory, trajectory_utc=True,
                        extrinsic=extrinsic or Extrinsic((0.0, 0.0, 0.0), (0.0, 0.0, 0.0)),
                        crs=crs or local_crs(*origin), notes=notes + [extrinsic_note])
    if crs is None:
        source.notes.append(f"pose frame taken as a local frame (x east, y north, z up) centred at lat {origin[0]:g}, "
                            f"lon {origin[1]:g}: a transverse Mercator CRS")
    return write_scan_recording(scans, source, out, calibration, name or folder.name, quiet)


def _numeric_stamp(stem: str) -> float | None:
    """A file name that is a number, as s since 1970 (ns above 1e15); None otherwise."""
    try:
        float(stem)
    except ValueError:
        return None
    return frame_time(stem)


def _trajectory(path: Path, frames: FramePoses, stems: list[str], scans: list[ScanPoints],
                pose_at: str) -> tuple[Trajectory, list[str]]:
    """Poses at the scans' times (and at the other named frames' times when the names are times), in UTC s."""
    reference = np.array([(s.time_s.max() if pose_at == "end" else s.time_s.min()) if len(s.time_s) else np.nan
                          for s in scans])
    named = all(n is not None for n in frames.names)
    if named:
        index = {n: i for i, n in enumerate(frames.names)}
        missing = [s for s in stems if s not in index]
        if missing:
            raise RecordingError(path, f"no pose for frame {missing[0]!r} ({len(missing)} PCD files without one)",
                                 expected="a line '<PCD file name without .pcd> r00 ... t2' per scan")
        matched = np.array([index[s] for s in stems])
    else:
        if len(frames.names) != len(stems):
            raise RecordingError(path, f"{len(frames.names)} poses for {len(stems)} PCD files",
                                 expected="one pose per PCD file, in file name order (KITTI poses)")
        matched = np.arange(len(stems))
    name_times = np.array([frame_time(n) if n is not None else np.nan for n in frames.names], dtype=np.float64)
    offsets = reference - name_times[matched]
    how = f"each at its scan's {'last' if pose_at == 'end' else 'first'} return"
    if np.all(np.isfinite(name_times)) and np.ptp(offsets[np.isfinite(offsets)]) <= _NAME_CLOCK_SPREAD_S:
        offset = float(np.median(offsets[np.isfinite(offsets)]))
        times, rows = name_times + offset, np.arange(len(frames.names))
        notes = [f"{len(rows)} poses from {path.name}, timed by their frame names shifted by {offset:+.3f} s onto the "
                 f"points' clock (the offset that puts the PCD frames' poses {how})"]
    else:
        keep = np.isfinite(reference)
        times, rows = reference[keep], matched[keep]
        notes = [f"{len(rows)} poses from {path.name}, {how}"]
    order = np.argsort(times, kind="stable")
    times, rows = times[order], rows[order]
    unique = np.concatenate([[True], np.diff(times) > 0])
    times, rows = times[unique], rows[unique]
    matrices = frames.matrices[rows]
    rpy = rpy_deg_from_rotation(Rotation.from_matrix(matrices[:, :, :3]))
    rpy[:, 2] = unwrap_deg(rpy[:, 2])
    trajectory = Trajectory(times, matrices[:, :, 3].copy(), rpy, geodetic=False)
    trajectory.validate(path)
    return trajectory, notes
