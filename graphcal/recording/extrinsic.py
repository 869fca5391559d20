"""Lidar -> body pose (extrinsic.yaml): p_body = R p_lidar + T."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from graphcal.common.errors import RecordingError
from graphcal.recording.rotations import rotation_from_rpy_deg


@dataclass(frozen=True)
class Extrinsic:
    """lever_arm_m: T in the body frame (x forward, y left, z up) [m];
    boresight_deg: roll, pitch, yaw [deg] with R = Rz(yaw) Ry(pitch) Rx(roll)."""

    lever_arm_m: tuple[float, float, float]
    boresight_deg: tuple[float, float, float]

    @property
    def R_body_lidar(self) -> np.ndarray:
        return rotation_from_rpy_deg(self.boresight_deg).as_matrix()

    @property
    def rotation(self) -> Rotation:
        return rotation_from_rpy_deg(self.boresight_deg)

    def lidar_to_body(self, p_lidar: np.ndarray) -> np.ndarray:
        """(N,3) lidar-frame points -> (N,3) body-frame points [m]."""
        return p_lidar @ self.R_body_lidar.T + np.asarray(self.lever_arm_m)

    def to_dict(self) -> dict:
        return {"lever_arm_m": [float(v) for v in self.lever_arm_m],
                "boresight_deg": [float(v) for v in self.boresight_deg]}

    @classmethod
    def from_dict(cls, data, path: str | Path = "extrinsic.yaml") -> Extrinsic:
        if not isinstance(data, dict):
            raise RecordingError(path, "not a mapping", expected="lever_arm_m and boresight_deg")
        values = {}
        for key in ("lever_arm_m", "boresight_deg"):
            raw = data.get(key)
            if raw is None:
                raise RecordingError(path, "missing field", field=key, expected="a list of 3 numbers")
            try:
                array = np.asarray(raw, dtype=np.float64)
            except (TypeError, ValueError):
                array = np.array([])
            if array.shape != (3,) or not np.all(np.isfinite(array)):
                raise RecordingError(path, f"value {raw!r}", field=key, expected="a list of 3 finite numbers")
            values[key] = tuple(float(v) for v in array)
        return cls(**values)
