"""Time-stamped poses and their interpolation: linear position, SLERP rotation, vectorised."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from graphcal.recording.rotations import rotation_from_rpy_deg, rpy_deg_from_rotation


@dataclass(frozen=True)
class PoseTrack:
    """Poses T_world_body(t): p_world = R(t) p_body + position(t).

    time [s] strictly increasing (N,), position_m (N,3) in the world frame, rotation (N).
    """

    time: np.ndarray
    position_m: np.ndarray
    rotation: Rotation

    @classmethod
    def from_rpy(cls, time, position_m, rpy_deg) -> PoseTrack:
        return cls(np.asarray(time, dtype=np.float64), np.asarray(position_m, dtype=np.float64),
                   rotation_from_rpy_deg(rpy_deg))

    @property
    def rpy_deg(self) -> np.ndarray:
        return rpy_deg_from_rotation(self.rotation)

    @property
    def span(self) -> tuple[float, float]:
        return float(self.time[0]), float(self.time[-1])

    def interpolate(self, t) -> tuple[np.ndarray, Rotation]:
        """Pose at times t (M,) [s] inside the span: (position (M,3) m, Rotation (M)).

        Raises ValueError for a time outside the span (no extrapolation)."""
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        if t.size and (t.min() < self.time[0] or t.max() > self.time[-1]):
            raise ValueError(f"times [{t.min():.6f}, {t.max():.6f}] s outside the poses' span "
                             f"[{self.time[0]:.6f}, {self.time[-1]:.6f}] s")
        index = np.clip(np.searchsorted(self.time, t, side="right") - 1, 0, len(self.time) - 2)
        t0, t1 = self.time[index], self.time[index + 1]
        alpha = ((t - t0) / (t1 - t0))[:, None]
        position = (1.0 - alpha) * self.position_m[index] + alpha * self.position_m[index + 1]
        # SLERP over the poses around t only (from the one before, where SLERP puts a time on a pose):
        # the same values as over the whole track, at a cost that does not grow with the track's length
        first, last = (max(int(index.min()) - 1, 0), int(index.max()) + 2) if t.size else (0, 2)
        return position, Slerp(self.time[first:last], self.rotation[first:last])(t)

    def transform(self, t, p_body) -> np.ndarray:
        """Body-frame points (M,3) observed at times t (M,) -> world frame (M,3) [m]."""
        position, rotation = self.interpolate(t)
        return rotation.apply(p_body) + position

    def resample(self, t) -> PoseTrack:
        position, rotation = self.interpolate(t)
        return PoseTrack(np.asarray(t, dtype=np.float64), position, rotation)
