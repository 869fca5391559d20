"""SO(3) helpers, vectorised over leading axes: skew, exponential, right Jacobian and its inverse."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

_SMALL = 1e-6


def skew(v: np.ndarray) -> np.ndarray:
    """(..., 3) -> (..., 3, 3) with skew(a) @ b = a x b."""
    v = np.asarray(v, dtype=np.float64)
    out = np.zeros(v.shape + (3,))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def exp(w: np.ndarray) -> np.ndarray:
    """Rotation vector (N, 3) [rad] -> rotation matrices (N, 3, 3)."""
    return Rotation.from_rotvec(np.asarray(w, dtype=np.float64).reshape(-1, 3)).as_matrix()


def log(R: np.ndarray) -> np.ndarray:
    """Rotation matrices (N, 3, 3) -> rotation vectors (N, 3) [rad]."""
    return Rotation.from_matrix(np.asarray(R, dtype=np.float64).reshape(-1, 3, 3)).as_rotvec()


def right_jacobian(w: np.ndarray) -> np.ndarray:
    """J_r(w) with Exp(w + d) = Exp(w) Exp(J_r(w) d) to first order; (N, 3) -> (N, 3, 3)."""
    w = np.asarray(w, dtype=np.float64).reshape(-1, 3)
    theta = np.linalg.norm(w, axis=1)
    small = theta < _SMALL
    t = np.where(small, 1.0, theta)
    a = np.where(small, 0.5 - theta**2 / 24, (1 - np.cos(t)) / t**2)
    b = np.where(small, 1.0 / 6 - theta**2 / 120, (t - np.sin(t)) / t**3)
    W = skew(w)
    return np.eye(3) - a[:, None, None] * W + b[:, None, None] * (W @ W)


def right_jacobian_inverse(w: np.ndarray) -> np.ndarray:
    """J_r(w)^-1 with Log(Exp(w) Exp(d)) = w + J_r(w)^-1 d to first order; (N, 3) -> (N, 3, 3)."""
    w = np.asarray(w, dtype=np.float64).reshape(-1, 3)
    theta = np.linalg.norm(w, axis=1)
    small = theta < _SMALL
    t = np.where(small, 1.0, theta)
    c = np.where(small, 1.0 / 12 + theta**2 / 720, 1 / t**2 - (1 + np.cos(t)) / (2 * t * np.sin(t)))
    W = skew(w)
    return np.eye(3) + 0.5 * W + c[:, None, None] * (W @ W)
