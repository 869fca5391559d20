"""World position of a return and its Jacobians with respect to every calibration key.

Chain (seed 000 eq. 4.2-4.4, seed 001 eq. 5.4), per return at its own time t:

    p_l = f(rho, theta; intrinsic offsets)                 eq. 4.2, sensor frame
    p_b = R_E p_l + t_E                                    extrinsic E = T_body_lidar
    q   = R_nav(t) p_b                                     INS attitude (fixed)
    translation corrections:  p_w = X_nav(t) + v(t) + q                      eq. 5.4
    pose corrections:         p_w = X_nav(t) + v(t) + Exp(w(t)) q
    (w, v)(t) = (1 - alpha) (w, v)_lo + alpha (w, v)_hi,  w_c = Log(R_c), v_c = t_c

so a pose correction turns the cloud about the vehicle, in world axes (well conditioned in UTM,
and it carries the yaw correction seed 001's conclusion asks for).

Jacobians follow GTSAM's conventions: a Pose3 key X is perturbed as X Exp(xi), tangent
xi = [omega, v] (rotation first); Point3 and Vector4 keys additively. They are exact at
xi = 0, i.e. at the current estimate, which is where GTSAM linearises.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from factors import so3
from factors.spherical import FactoryTerms, to_xyz_with_jacobian


@dataclass(frozen=True)
class Returns:
    """Fixed per-return data of a block (N returns): raw measurements, factory terms, the INS
    pose interpolated at each return's time (R_nav (N,3,3), X_nav (N,3) m, world frame, usually
    minus a local origin) and the interpolation weight alpha (N,) between its two control times."""

    range_m: np.ndarray
    azimuth_rad: np.ndarray
    factory: FactoryTerms
    R_nav: np.ndarray
    X_nav: np.ndarray
    alpha: np.ndarray


@dataclass(frozen=True)
class Corrections:
    """Current trajectory corrections at the control times before (lo) and after (hi) each
    return: translations (N,3) m and, for pose corrections, rotations (N,3,3) (None otherwise)."""

    translation_lo: np.ndarray
    translation_hi: np.ndarray
    rotation_lo: np.ndarray | None = None
    rotation_hi: np.ndarray | None = None


@dataclass(frozen=True)
class WorldJacobians:
    """d p_w / d key for each key, (N, 3, dim): intrinsic (4), extrinsic (6), control lo/hi (3 or 6)."""

    intrinsic: np.ndarray
    extrinsic: np.ndarray
    control_lo: np.ndarray
    control_hi: np.ndarray


def world_points(returns: Returns, offsets: np.ndarray, R_E: np.ndarray, t_E: np.ndarray,
                 corrections: Corrections, jacobians: bool = True) -> tuple[np.ndarray, WorldJacobians | None]:
    """(N,3) world points [m] and, if asked, their Jacobians. offsets: (N,4) per return."""
    p_l, J_intrinsic = to_xyz_with_jacobian(returns.range_m, returns.azimuth_rad, returns.factory, offsets, jacobians)
    p_b = p_l @ R_E.T + t_E
    q = np.einsum("nij,nj->ni", returns.R_nav, p_b)
    a = returns.alpha[:, None]
    v = (1 - a) * corrections.translation_lo + a * corrections.translation_hi
    pose = corrections.rotation_lo is not None
    if pose:
        w_lo, w_hi = so3.log(corrections.rotation_lo), so3.log(corrections.rotation_hi)
        w = (1 - a) * w_lo + a * w_hi
        R_w = so3.exp(w)
        p_w = returns.X_nav + v + np.einsum("nij,nj->ni", R_w, q)
    else:
        p_w = returns.X_nav + v + q
    if not jacobians:
        return p_w, None

    M = R_w @ returns.R_nav if pose else returns.R_nav  # d p_w / d p_b
    MR_E = M @ R_E
    intrinsic = MR_E @ J_intrinsic
    extrinsic = np.concatenate([-MR_E @ so3.skew(p_l), np.broadcast_to(MR_E, MR_E.shape)], axis=2)
    if pose:
        d_rotated_dw = -R_w @ so3.skew(q) @ so3.right_jacobian(w)
        lo = np.concatenate([d_rotated_dw @ so3.right_jacobian_inverse(w_lo), corrections.rotation_lo], axis=2)
        hi = np.concatenate([d_rotated_dw @ so3.right_jacobian_inverse(w_hi), corrections.rotation_hi], axis=2)
    else:
        lo = hi = np.broadcast_to(np.eye(3), (len(p_w), 3, 3))
    aa = a[:, :, None]
    return p_w, WorldJacobians(intrinsic, extrinsic, (1 - aa) * lo, aa * hi)
