"""odometry.csv: cumulative wheel angles [rad] and an optional gyro yaw rate [rad/s]."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from graphcal.common.errors import RecordingError
from graphcal.common.tables import read_csv_columns, write_csv_columns

COLUMNS = ("time", "wheel_left_rad", "wheel_right_rad")
OPTIONAL = ("yaw_rate_rad_s",)


@dataclass(frozen=True)
class Odometry:
    """Wheel odometry. wheel_radius_m and track_m come from recording.yaml."""

    time: np.ndarray
    wheel_left_rad: np.ndarray
    wheel_right_rad: np.ndarray
    wheel_radius_m: float
    track_m: float
    yaw_rate_rad_s: np.ndarray | None = None

    def params(self) -> dict:
        return {"wheel_radius_m": float(self.wheel_radius_m), "track_m": float(self.track_m)}

    def save_csv(self, path: Path) -> None:
        columns = [self.time, self.wheel_left_rad, self.wheel_right_rad]
        header = COLUMNS + (OPTIONAL if self.yaw_rate_rad_s is not None else ())
        if self.yaw_rate_rad_s is not None:
            columns.append(self.yaw_rate_rad_s)
        write_csv_columns(path, header, np.column_stack(columns), formats="%.9f")

    @classmethod
    def load_csv(cls, path: Path, params, manifest: str | Path = "recording.yaml") -> Odometry:
        if not isinstance(params, dict):
            raise RecordingError(manifest, "odometry.csv exists but recording.yaml has no odometry section",
                                 field="odometry", expected="{wheel_radius_m, track_m}")
        for key in ("wheel_radius_m", "track_m"):
            value = params.get(key)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0:
                raise RecordingError(manifest, f"value {value!r}", field=f"odometry.{key}",
                                     expected="a positive length in metres")
        header, values = read_csv_columns(path, (COLUMNS,), optional=OPTIONAL)
        bad = np.flatnonzero(np.diff(values[:, 0]) <= 0)
        if bad.size:
            raise RecordingError(path, "time does not increase", field="time", row=int(bad[0]) + 2,
                                 expected="strictly increasing times")
        yaw_rate = values[:, 3] if len(header) == 4 else None
        return cls(values[:, 0], values[:, 1], values[:, 2], float(params["wheel_radius_m"]),
                   float(params["track_m"]), yaw_rate)
