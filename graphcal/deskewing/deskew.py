"""Scan deskew (seed 002): every return of a revolution moved into the lidar frame at the end of
that revolution, with the motion of the vehicle during the sweep.

Output frame: the end-of-scan LIDAR frame L_end, i.e. the sensor frame of frames.md at the time
of the revolution's last return, as a sensor driver outputs a scan. For the return k fired at t_k:

    p_Lend = T_lidar_body · T_ref_body(t_end)^-1 · T_ref_body(t_k) · T_body_lidar · p_lidar,k

T_ref_body(t) is the body's motion in any frame fixed to the ground: the INS trajectory
(source="ins": linear position and SLERP at each time) or the poses integrated from the wheel
odometry (source="odometry": eq. 1-3, planar; the per-azimuth pose of eq. 5 is this motion at
the return's time, and eq. 6 moves the return with it). source="none" leaves every return
where the sensor measured it: the raw scan, as if the head had not moved during the sweep.

Speed: the relative pose is evaluated on a grid of knots per revolution (every KNOT_STEP_S), each
return takes its nearest knot, and one batched transform moves the returns chunk by chunk.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy.spatial.transform import Rotation

import graphcal.recording.points as points_module
from graphcal.deskewing.dead_reckoning import odometry_track
from graphcal.common.errors import ConfigError, RecordingError
from graphcal.recording.extrinsic import Extrinsic
from graphcal.recording.poses import PoseTrack
from graphcal.common.progress import progress

Source = Literal["ins", "odometry", "none"]
SOURCES = ("ins", "odometry", "none")
# knot spacing of the relative pose inside a revolution [s]: each return takes its nearest knot,
# at most 10 us from its time, so it moves by at most (v + omega r) 1e-5 s off its place (0.5 mm
# at 14 m/s and 25 deg/s at 100 m)
KNOT_STEP_S = 2e-5
POSE_STEP_S = 1e-3  # the exact relative pose every ms, linear in between (error < 1e-7 rad)
CHUNK_ROWS = 1 << 14  # returns transformed at once
THREADS = min(2, os.cpu_count() or 1)
_COLUMNS = ["time", "fibre", "range", "azimuth", "intensity"]


def scan_ids(azimuth_rad: np.ndarray, start: int = 0) -> np.ndarray:
    """Revolution counter from the encoder azimuth (a new revolution where it wraps back by
    more than pi), for recordings without a `scan` column."""
    wraps = np.diff(np.asarray(azimuth_rad, dtype=np.float64)) < -np.pi
    return start + np.concatenate([[0], np.cumsum(wraps)])


def scan_offsets(scan: np.ndarray) -> np.ndarray:
    """Row offsets (S+1,) of the runs of equal scan ids: scan k is rows offsets[k]:offsets[k+1]."""
    starts = np.flatnonzero(np.diff(scan)) + 1
    return np.concatenate([[0], starts, [len(scan)]])


def relative_lidar_poses(track: PoseTrack, extrinsic: Extrinsic, time_s: np.ndarray,
                         end_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """T_Lend_L(t): the lidar pose at time_s (M,) in the lidar frame at end_s (M,), as rotation
    matrices (M,3,3) and translations (M,3) [m]."""
    position, rotation = track.interpolate(np.concatenate([time_s, end_s]))
    m = len(time_s)
    R_end_inv = rotation[m:].inv()
    R_rel = R_end_inv * rotation[:m]
    t_rel = R_end_inv.apply(position[:m] - position[m:])
    R_bl, lever = extrinsic.rotation, np.asarray(extrinsic.lever_arm_m)
    R = (R_bl.inv() * R_rel * R_bl).as_matrix()
    t = R_bl.inv().apply(R_rel.apply(lever) + t_rel - lever)
    return R, t


def deskew_points(time_s: np.ndarray, xyz_lidar_m: np.ndarray, offsets: np.ndarray, track: PoseTrack,
                  extrinsic: Extrinsic) -> np.ndarray:
    """Returns of whole revolutions (rows offsets[k]:offsets[k+1] for revolution k, time-sorted)
    from the lidar frame at their own time to the lidar frame at their revolution's last
    return (N,3) [m]. The motion is T_ref_body(t) of `track`."""
    knots, index = _knots(time_s, offsets, track, extrinsic)
    out = np.empty((len(time_s), 3))
    _in_chunks(len(time_s), lambda rows: _apply(knots, index[rows], xyz_lidar_m[rows], out[rows]))
    return out


def _grid(first: np.ndarray, last: np.ndarray, step_s: float):
    """Evenly spaced knots from first to last (S,) of each revolution, no more than step_s apart:
    (times (K,), index of each revolution's first knot (S+1,), revolution of each knot, index
    of each knot in its revolution, actual spacing (S,))."""
    span = last - first
    n_knots = np.maximum(np.ceil(span / step_s).astype(np.int64) + 1, 2)
    spacing = span / (n_knots - 1)
    start = np.concatenate([[0], np.cumsum(n_knots)])
    revolution = np.repeat(np.arange(len(first)), n_knots)
    in_revolution = np.arange(start[-1]) - start[revolution]
    times = np.minimum(first[revolution] + spacing[revolution] * in_revolution, last[revolution])
    return times, start, revolution, in_revolution, spacing


def _knots(time_s, offsets, track, extrinsic):
    """T_Lend_L on a fine grid of each revolution (every <= KNOT_STEP_S) as a (12, K) table
    (rotation row-major, then translation), and the nearest knot of each return. The exact
    pose is computed every POSE_STEP_S and interpolated linearly to the fine grid."""
    counts = np.diff(offsets)
    first, last = time_s[offsets[:-1]], time_s[offsets[1:] - 1]
    coarse_time, coarse_start, revolution, _, coarse_step = _grid(first, last, POSE_STEP_S)
    R, t = relative_lidar_poses(track, extrinsic, coarse_time, last[revolution])
    coarse = np.concatenate([R.reshape(-1, 9), t], axis=1).T
    _, fine_start, revolution, in_revolution, fine_step = _grid(first, last, KNOT_STEP_S)
    n_coarse = np.diff(coarse_start)[revolution]
    u = in_revolution * _ratio(fine_step, coarse_step)[revolution]
    k = np.minimum(u.astype(np.int64), n_coarse - 2)
    alpha = u - k
    k += coarse_start[revolution]
    fine = coarse[:, k] + alpha * (coarse[:, k + 1] - coarse[:, k])
    index = ((time_s - np.repeat(first, counts)) * np.repeat(_ratio(1.0, fine_step), counts)
             + np.repeat(fine_start[:-1] + 0.5, counts)).astype(np.int64)
    return np.ascontiguousarray(fine), index


def _ratio(numerator, denominator: np.ndarray) -> np.ndarray:
    """numerator / denominator, 0 where the denominator is 0 (a revolution of one instant)."""
    safe = np.where(denominator > 0, denominator, 1.0)
    return np.where(denominator > 0, numerator / safe, 0.0)


def _apply(knots: np.ndarray, index: np.ndarray, xyz: np.ndarray, out: np.ndarray) -> None:
    """out = T(knot) xyz for one chunk of returns: knots (12, K), index (n,), xyz and out (n,3)."""
    M = knots.take(index, axis=1)
    x, y, z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    for row in range(3):
        column = out[:, row]
        np.multiply(M[3 * row], x, out=column)
        column += M[3 * row + 1] * y
        column += M[3 * row + 2] * z
        column += M[9 + row]


def _in_chunks(n: int, job) -> None:
    """job(slice) over chunks of CHUNK_ROWS rows (small enough for the cache), on THREADS threads."""
    chunks = [slice(start, start + CHUNK_ROWS) for start in range(0, n, CHUNK_ROWS)]
    if THREADS > 1 and len(chunks) > 1:
        with ThreadPoolExecutor(THREADS) as pool:
            list(pool.map(job, chunks))
    else:
        for rows in chunks:
            job(rows)


@dataclass(frozen=True)
class Scan:
    """One revolution: its returns in the end-of-scan lidar frame L_end.

    index: 0, 1, ... in time order; scan_id: the recording's revolution counter; time_end_s: the
    time of its last return [s]; xyz_m (n,3) [m, L_end]; time_s, fibre, intensity (n,): of the
    returns, which are rows first_row .. first_row + n - 1 of points.parquet; rotation and
    position of L_end in the world [m], from the INS trajectory (T_world_lidar_end).
    """

    index: int
    scan_id: int
    time_end_s: float
    xyz_m: np.ndarray
    time_s: np.ndarray
    fibre: np.ndarray
    intensity: np.ndarray
    first_row: int
    rotation_world_lidar: Rotation
    position_world_lidar_m: np.ndarray

    @property
    def rows(self) -> slice:
        """Its returns' rows in points.parquet (and truth/points.parquet)."""
        return slice(self.first_row, self.first_row + len(self.xyz_m))

    def world_points(self, rotation: Rotation | None = None, position_m: np.ndarray | None = None) -> np.ndarray:
        """The scan placed in the world with one pose of L_end (default: the INS pose)."""
        rotation = self.rotation_world_lidar if rotation is None else rotation
        position_m = self.position_world_lidar_m if position_m is None else position_m
        return rotation.apply(self.xyz_m) + position_m


def motion_track(recording, source: Source, use_gyro: bool = True) -> PoseTrack | None:
    """T_ref_body(t) used to deskew: the INS trajectory, the integrated odometry, or None (raw)."""
    if source not in SOURCES:
        raise ConfigError(f"deskew source {source!r}: expected one of {', '.join(SOURCES)}")
    if source == "ins":
        return recording.world.poses
    if source == "none":
        return None
    if recording.odometry is None:
        path = recording.path / "odometry.csv" if recording.path is not None else "odometry.csv"
        raise RecordingError(path, "file not found", expected="wheel odometry to deskew with source='odometry' "
                                                              "(or use source='ins')")
    return odometry_track(recording.odometry, use_gyro)


def _check_covered(track: PoseTrack, time_s: np.ndarray, source: Source, recording) -> None:
    start, end = track.span
    if time_s[0] < start or time_s[-1] > end:
        name = "odometry.csv" if source == "odometry" else "trajectory.csv"
        path = recording.path / name if recording.path is not None else name
        raise RecordingError(path, f"samples span [{start:.6f}, {end:.6f}] s", field="time",
                             expected=f"samples covering the returns' span [{time_s[0]:.6f}, {time_s[-1]:.6f}] s")


def iter_scans(recording, source: Source = "ins", use_gyro: bool = True, quiet: bool = False) -> Iterator[Scan]:
    """Deskew a recording revolution by revolution, reading its returns in batches.

    Revolutions come from the `scan` column, or from the azimuth wrap when it is absent; the
    first and last ones may be partial. World poses of L_end always come from the INS."""
    deskewer = _Deskewer(recording, source, motion_track(recording, source, use_gyro))
    has_scan = "scan" in recording.points.column_names
    carry: dict[str, np.ndarray] | None = None
    batches = recording.points.iter_batches(_COLUMNS + (["scan"] if has_scan else []))
    n_batches = -(-len(recording.points) // points_module.BATCH_ROWS)
    for batch in progress(batches, f"deskewing {recording.name} ({source})", total=n_batches, quiet=quiet):
        if not has_scan:  # go on counting from the previous batch
            wrapped = carry is not None and batch["azimuth"][0] - carry["azimuth"][-1] < -np.pi
            batch["scan"] = scan_ids(batch["azimuth"], 0 if carry is None else int(carry["scan"][-1]) + wrapped)
        if carry is not None:
            batch = {name: np.concatenate([carry[name], batch[name]]) for name in batch}
        offsets = scan_offsets(batch["scan"])
        if np.any(np.diff(batch["scan"][offsets[:-1]]) < 0):
            raise RecordingError(recording._source("points.parquet"), "the revolution counter goes back",
                                 field="scan", expected="a counter that never decreases with time")
        complete = offsets[-2]  # the last revolution may go on in the next batch
        carry = {name: values[complete:] for name, values in batch.items()}
        if complete > 0:
            yield from deskewer.scans({name: values[:complete] for name, values in batch.items()}, offsets[:-1])
    if carry is not None and len(carry["time"]):
        yield from deskewer.scans(carry, np.array([0, len(carry["time"])]))


class _Deskewer:
    """Deskews batches of whole revolutions and numbers them."""

    def __init__(self, recording, source: Source, track: PoseTrack | None):
        self.recording, self.source, self.track = recording, source, track
        self.index, self.row = 0, 0

    def scans(self, batch: dict[str, np.ndarray], offsets: np.ndarray) -> Iterator[Scan]:
        recording, extrinsic, sensor = self.recording, self.recording.extrinsic, self.recording.sensor
        time, fibre = batch["time"], batch["fibre"].astype(np.intp)
        knots = None
        if self.track is not None:
            _check_covered(self.track, time, self.source, recording)
            knots, knot_of_return = _knots(time, offsets, self.track, extrinsic)
        xyz = np.empty((len(time), 3))

        def job(rows: slice) -> None:  # eq. 4.2, then the move to L_end (eq. 6), chunk by chunk
            p_lidar = sensor.to_xyz(fibre[rows], batch["range"][rows], batch["azimuth"][rows])
            if knots is None:
                xyz[rows] = p_lidar
            else:
                _apply(knots, knot_of_return[rows], p_lidar, xyz[rows])

        _in_chunks(len(time), job)
        end = time[offsets[1:] - 1]
        _check_covered(recording.world.poses, end, "ins", recording)
        position, rotation = recording.world.poses.interpolate(end)
        rotation_lidar = rotation * extrinsic.rotation
        position_lidar = position + rotation.apply(np.asarray(extrinsic.lever_arm_m))
        for k in range(len(offsets) - 1):
            rows = slice(offsets[k], offsets[k + 1])
            yield Scan(index=self.index, scan_id=int(batch["scan"][rows.start]), time_end_s=float(end[k]),
                       xyz_m=xyz[rows], time_s=time[rows], fibre=batch["fibre"][rows],
                       intensity=batch["intensity"][rows], first_row=self.row + rows.start,
                       rotation_world_lidar=rotation_lidar[k], position_world_lidar_m=position_lidar[k])
            self.index += 1
        self.row += len(time)


def deskew(recording, source: Source = "ins", use_gyro: bool = True, quiet: bool = False) -> list[Scan]:
    """Every revolution of `recording` in its end-of-scan lidar frame (seed 002), in time order.

    source: "ins" (trajectory.csv interpolated at each return), "odometry" (odometry.csv, eq.
    1-3 and 5-6; the gyro yaw rate when present and use_gyro) or "none" (raw scans)."""
    return list(iter_scans(recording, source, use_gyro, quiet))
