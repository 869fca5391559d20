"""Applanix SBET (smoothed best estimate of trajectory) -> Trajectory (trajectory.csv).

An SBET file is a sequence of 136-byte records of 17 little-endian float64: GPS seconds of
week, latitude, longitude [rad], altitude [m], x/y/z velocity [m/s], roll, pitch, platform
heading, wander angle [rad], x/y/z acceleration [m/s2], x/y/z angular rate [rad/s].

The attitude is the usual INS one: body frame x forward, y right, z down (FRD), relative to
local North-East-Down, R_ned_frd = Rz(heading) Ry(pitch) Rx(roll), heading clockwise from true
north. The recording's body frame is x forward, y left, z up, relative to East-North-Up, with
R_enu_flu = Rz(yaw) Ry(pitch') Rx(roll'). With R_enu_ned = [[0,1,0],[1,0,0],[0,0,-1]] and
R_frd_flu = diag(1,-1,-1), R_enu_flu = R_enu_ned R_ned_frd R_frd_flu gives

    roll' = roll,   pitch' = -pitch,   yaw = 90 deg - heading

(tests/test_importers_trajectory.py checks it with the matrices). The platform heading is used
as the true heading and the wander angle is not applied, as PDAL's and other SBET readers do.
Times stay GPS seconds of week, the time base of every graphcal importer.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from graphcal.common.errors import RecordingError
from graphcal.recording.rotations import unwrap_deg
from graphcal.recording.trajectory import Trajectory

FIELDS = ("time", "lat", "lon", "alt", "velocity_x", "velocity_y", "velocity_z", "roll", "pitch", "heading",
          "wander", "acceleration_x", "acceleration_y", "acceleration_z", "rate_x", "rate_y", "rate_z")
RECORD = np.dtype([(name, "<f8") for name in FIELDS])


def read_sbet(path: str | Path) -> np.ndarray:
    """The records of an SBET file as a structured array (RECORD), checked: whole records, finite
    values, latitude/longitude in radians, strictly increasing time."""
    path = Path(path)
    if not path.is_file():
        raise RecordingError(path, "file not found")
    size = path.stat().st_size
    if size == 0 or size % RECORD.itemsize:
        raise RecordingError(path, f"{size} bytes: record {size // RECORD.itemsize} has {size % RECORD.itemsize} "
                                   f"of its {RECORD.itemsize} bytes" if size else "empty file",
                             expected=f"a multiple of {RECORD.itemsize} bytes (17 little-endian float64 per record)")
    records = np.fromfile(path, dtype=RECORD)
    for name in FIELDS:
        bad = np.flatnonzero(~np.isfinite(records[name]))
        if bad.size:
            raise RecordingError(path, f"value {records[name][bad[0]]!r}", field=name, row=int(bad[0]),
                                 expected="finite numbers")
    for name, limit in (("lat", np.pi / 2), ("lon", np.pi)):
        bad = np.flatnonzero(np.abs(records[name]) > limit + 1e-9)
        if bad.size:
            raise RecordingError(path, f"value {records[name][bad[0]]!r}", field=name, row=int(bad[0]),
                                 expected=f"radians within +-{limit:.4f} (not a little-endian SBET?)")
    bad = np.flatnonzero(np.diff(records["time"]) <= 0)
    if bad.size:
        raise RecordingError(path, f"time {records['time'][bad[0] + 1]!r} after {records['time'][bad[0]]!r}",
                             field="time", row=int(bad[0]) + 1, expected="strictly increasing GPS seconds of week")
    return records


def ned_to_enu_attitude_deg(roll_rad, pitch_rad, heading_rad) -> np.ndarray:
    """INS attitude (FRD body vs NED, heading clockwise from north) -> (N, 3) roll, pitch, yaw [deg]
    of the FLU body vs ENU (yaw counter-clockwise from east, the first within +-180, then unwrapped)."""
    yaw = unwrap_deg(np.mod(90.0 - np.degrees(heading_rad) + 180.0, 360.0) - 180.0)
    return np.column_stack([np.degrees(roll_rad), -np.degrees(pitch_rad), yaw])


def import_sbet(path: str | Path, time_range: tuple[float, float] | None = None) -> Trajectory:
    """SBET -> geodetic Trajectory (lat/lon deg, altitude as in the file, ENU attitude deg).

    time_range: keep only the poses that cover [start, end] (GPS seconds of week)."""
    records = read_sbet(path)
    position = np.column_stack([np.degrees(records["lat"]), np.degrees(records["lon"]), records["alt"]])
    trajectory = Trajectory(time=records["time"].copy(), position=position,
                            rpy_deg=ned_to_enu_attitude_deg(records["roll"], records["pitch"], records["heading"]),
                            geodetic=True)
    if time_range is not None:
        trajectory = trajectory.between(*time_range)
        trajectory.validate(Path(path))
    return trajectory
