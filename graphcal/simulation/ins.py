"""The true trajectory, and the GNSS/INS trajectory recorded from it (noise, error, drift)."""

from __future__ import annotations

import numpy as np
from pyproj import CRS

from factors.effects import Effect
from graphcal.recording.geodesy import enu_to_grid_rotation, grid_to_geodetic, map_factors
from graphcal.recording.poses import PoseTrack
from graphcal.recording.rotations import rpy_deg_from_rotation, unwrap_deg
from graphcal.simulation.drive import Drive
from graphcal.simulation.ins_drift import ins_drift
from graphcal.simulation.scenario import InsErrors
from graphcal.recording.trajectory import Trajectory


def sample_times(start_s: float, end_s: float, rate_hz: float) -> np.ndarray:
    """start, start + 1/rate, ... and end itself; no two times closer than half a period."""
    n = int(np.floor((end_s - start_s) * rate_hz + 0.5))
    times = start_s + np.arange(n) / rate_hz
    return np.r_[times[times < end_s - 0.5 / rate_hz], end_s]


def true_poses(drive: Drive, start_time_s: float, duration_s: float, rate_hz: float) -> PoseTrack:
    """T_local_body sampled at rate_hz over [start, start + duration] (local frame, m, deg)."""
    elapsed = sample_times(0.0, duration_s, rate_hz)
    xyz, yaw = drive.pose_at(elapsed)
    rpy = np.column_stack([np.zeros_like(yaw), np.zeros_like(yaw), yaw])
    return PoseTrack.from_rpy(start_time_s + elapsed, xyz, rpy)


def recorded_poses(truth: PoseTrack, errors: InsErrors, effects: list[Effect],
                   rng: np.random.Generator) -> PoseTrack:
    """What the GNSS/INS writes: truth resampled at errors.rate_hz, plus a piecewise-linear
    position error, white noise, the INS drift (random walks, slow bias, jumps: ins_drift.py) and
    the switched-on INS effects (e.g. heading drift, projection scale)."""
    t0, t1 = truth.span
    time = sample_times(t0, t1, errors.rate_hz)
    ins = truth.resample(time)
    position = ins.position_m.copy()
    if errors.piecewise_error_m > 0:
        knots = np.arange(t0, t1 + errors.piecewise_interval_s, errors.piecewise_interval_s)
        error = rng.normal(0.0, errors.piecewise_error_m / np.sqrt(3.0), (len(knots), 3))
        position += np.column_stack([np.interp(time, knots, error[:, k]) for k in range(3)])
    position += rng.normal(0.0, errors.position_noise_m, position.shape)
    rpy = unwrap_deg_columns(ins.rpy_deg) + rng.normal(0.0, errors.attitude_noise_deg, position.shape)
    drift_m, heading_drift_deg = ins_drift(time, errors, rng)
    position += drift_m
    rpy[:, 2] += heading_drift_deg
    for effect in effects:
        rpy = effect.ins_rpy(time - t0, rpy)
        position = effect.ins_position(time - t0, position)
    return PoseTrack.from_rpy(time, position, rpy)


def unwrap_deg_columns(rpy_deg: np.ndarray) -> np.ndarray:
    return np.column_stack([unwrap_deg(rpy_deg[:, k]) for k in range(3)])


def to_trajectory(poses: PoseTrack, origin_m, crs: CRS, geodetic: bool) -> Trajectory:
    """Local poses -> trajectory.csv content, projected (grid = local + origin) or geodetic."""
    grid = poses.position_m + np.asarray(origin_m)
    if not geodetic:
        return Trajectory(poses.time, grid, unwrap_deg_columns(poses.rpy_deg), geodetic=False)
    lat_lon_alt = grid_to_geodetic(crs, grid)
    _, convergence = map_factors(crs, lat_lon_alt[:, 1], lat_lon_alt[:, 0])
    rotation_enu = enu_to_grid_rotation(convergence).inv() * poses.rotation
    return Trajectory(poses.time, lat_lon_alt, unwrap_deg_columns(rpy_deg_from_rotation(rotation_enu)), geodetic=True)
