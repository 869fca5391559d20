"""The trajectory of an imported capture: the one given, cut to the returns, or a static one at a position."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from graphcal.common.errors import RecordingError
from graphcal.recording.trajectory import Trajectory

MARGIN_S = 1e-3  # a static trajectory starts and ends this far beyond the returns (CSV rounding)


def capture_trajectory(path: Path, time: np.ndarray, week: int, trajectory: Trajectory | None,
                       position: tuple[float, float, float] | None, attitude_deg, notes: list[str],
                       where: str = "the position given") -> Trajectory:
    """trajectory (GPS seconds of week) cut to the returns' span +- 1 s, or RecordingError when it does not
    cover them; without one, a STATIC trajectory at position (lat, lon deg, ellipsoidal height m) with
    attitude_deg (roll, pitch, yaw vs ENU), `where` saying where the position comes from. Notes what it did."""
    if trajectory is not None:
        if time[0] < trajectory.time[0] or time[-1] > trajectory.time[-1]:
            raise RecordingError(path, f"returns span [{time[0]:.3f}, {time[-1]:.3f}] s of GPS week {week}, the "
                                       f"trajectory [{trajectory.time[0]:.3f}, {trajectory.time[-1]:.3f}] s",
                                 expected="a trajectory in GPS seconds of week covering the returns")
        trajectory = trajectory.between(time[0] - 1.0, time[-1] + 1.0)
        notes.append(f"trajectory given: {len(trajectory.time)} poses kept (the returns' span +- 1 s)")
        return trajectory
    if position is None:
        raise RecordingError(path, "no trajectory given and no position",
                             expected="a position (--position LAT,LON,ALT) or a trajectory (--trajectory)")
    start, end = float(time[0]) - MARGIN_S, float(time[-1]) + MARGIN_S
    notes.append(f"STATIC trajectory (the sensor is assumed not to move): lat {position[0]:.7f}, lon "
                 f"{position[1]:.7f}, height {position[2]:.2f} m ({where}), attitude {tuple(attitude_deg)} deg vs ENU, "
                 f"over [{start:.6f}, {end:.6f}] s")
    return Trajectory(time=np.array([start, end]), position=np.array([position, position], dtype=np.float64),
                      rpy_deg=np.array([attitude_deg, attitude_deg], dtype=np.float64), geodetic=True)
