"""Roll/pitch/yaw conventions of RECORDING.md: R = Rz(yaw) Ry(pitch) Rx(roll), angles in degrees.

Thin wrappers over scipy's Rotation so that one convention is spelt in one place.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

# Intrinsic z-y'-x'' (yaw, pitch, roll): R = Rz(yaw) Ry(pitch) Rx(roll).
_SEQ = "ZYX"


def rotation_from_rpy_deg(rpy_deg) -> Rotation:
    """(..., 3) roll, pitch, yaw [deg] -> Rotation with R = Rz(yaw) Ry(pitch) Rx(roll)."""
    rpy = np.asarray(rpy_deg, dtype=np.float64)
    return Rotation.from_euler(_SEQ, rpy[..., ::-1], degrees=True)


def rpy_deg_from_rotation(rotation: Rotation) -> np.ndarray:
    """Rotation -> (..., 3) roll, pitch, yaw [deg], inverse of rotation_from_rpy_deg."""
    return rotation.as_euler(_SEQ, degrees=True)[..., ::-1]


def unwrap_deg(angle_deg: np.ndarray) -> np.ndarray:
    """Unwrap a time series of angles in degrees (removes 360 deg jumps)."""
    return np.degrees(np.unwrap(np.radians(angle_deg)))
