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

from dataclasses import dataclass, replace

import numpy as np

from factors import so3
from factors.spherical import FactoryTerms, to_xyz, to_xyz_with_jacobian


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
    return: translations (N,3) m and, for pose corrections, rotations (N,3,3) and optionally their
    rotation vectors (N,3) (None otherwise)."""

    translation_lo: np.ndarray
    translation_hi: np.ndarray
    rotation_lo: np.ndarray | None = None
    rotation_hi: np.ndarray | None = None
    rotvec_lo: np.ndarray | None = None
    rotvec_hi: np.ndarray | None = None

    def translation(self, alpha: np.ndarray) -> np.ndarray:
        """(N,3) [m] the translation interpolated at each return's weight alpha (N,) between its lo and hi control."""
        return self.translation_lo + alpha[:, None] * (self.translation_hi - self.translation_lo)

    def rotvecs(self) -> tuple[np.ndarray, np.ndarray]:
        """Log of the lo/hi rotations (N,3) [rad]: the given ones (callers that know them per
        control pass them, a Log per return is the costliest step of a block), else computed."""
        if self.rotvec_lo is not None:
            return self.rotvec_lo, self.rotvec_hi
        return so3.log(self.rotation_lo), so3.log(self.rotation_hi)


@dataclass(frozen=True)
class WorldJacobians:
    """d p_w / d key for each key, (N, 3, dim): intrinsic (4), extrinsic (6), control lo/hi (3 or 6)."""

    intrinsic: np.ndarray
    extrinsic: np.ndarray
    control_lo: np.ndarray
    control_hi: np.ndarray


@dataclass(frozen=True)
class Turn:
    """The interpolated rotation correction R_w = Exp(w), w = (1 - alpha) w_lo + alpha w_hi, of
    each return (None for translation-only corrections), and G_lo/hi = J_r(w) J_r(w_lo/hi)^-1 (1 - alpha)/alpha,
    so that d(R_w u)/d(rotation of the lo/hi control) = -R_w [u]x G_lo/hi. Computed once for a set
    of returns, it serves both their points and their normals."""

    R_w: np.ndarray | None
    G_lo: np.ndarray | None = None
    G_hi: np.ndarray | None = None

    @classmethod
    def of(cls, corrections: Corrections, alpha: np.ndarray, jacobians: bool) -> Turn:
        if corrections.rotation_lo is None:
            return cls(None)
        a = alpha[:, None]
        w_lo, w_hi = corrections.rotvecs()
        w = (1 - a) * w_lo + a * w_hi
        if not jacobians:
            return cls(so3.exp(w))
        Jr = so3.right_jacobian(w)
        return cls(so3.exp(w), (1 - a[:, :, None]) * Jr @ so3.right_jacobian_inverse(w_lo),
                   a[:, :, None] * Jr @ so3.right_jacobian_inverse(w_hi))

    def apply(self, u: np.ndarray) -> np.ndarray:
        return u if self.R_w is None else np.einsum("nij,nj->ni", self.R_w, u)

    def after(self, R_nav: np.ndarray, R_E: np.ndarray) -> np.ndarray:
        """R_w R_nav R_E (N,3,3): lidar axes -> world axes once corrected (R_nav R_E as one matrix product over
        every return's rows)."""
        R_nav_E = (R_nav.reshape(-1, 3) @ R_E).reshape(-1, 3, 3)
        return R_nav_E if self.R_w is None else self.R_w @ R_nav_E

    def d_rotation(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """d(R_w u)/d(rotation of the lo, hi control), (N, 3, 3) each."""
        turned = -self.R_w @ so3.skew(u)
        return turned @ self.G_lo, turned @ self.G_hi


@dataclass(frozen=True)
class Placed:
    """Returns placed in the world by world_points: the returns with their offsets (N,4), the extrinsic's
    rotation R_E (3,3), the corrections with their turn, and the world points [m] (N,3) with their
    Jacobians (what the channel Jacobians of factors.channels start from)."""

    returns: Returns
    offsets: np.ndarray
    R_E: np.ndarray
    corrections: Corrections
    turn: Turn
    points_w: np.ndarray
    J: WorldJacobians


def on_stand_ins(measured: Returns, offsets: np.ndarray, shift_m: np.ndarray) -> tuple[Returns, np.ndarray]:
    """The returns with their ranges' stand-ins (range + shift_m [m], graphcal.calibration.association.Sight), and the
    offset (N,3) [m] in each one's sensor frame from eq. 4.2's point at the stand-in range to the
    measured one at the intrinsic offsets (N,4): world_points with held_lidar = that offset gives the
    measured points at those offsets, but the Jacobians of the intrinsic angles, which scale with the
    range, do not carry each return's own range noise (with it, the noise times itself biases the
    angles: measured on sim2_street, 1 cm noise, pairs made on the true cloud, the elevation errors 9x
    their spread under the same noise values shuffled among the returns; 1.3x with the stand-ins)."""
    stand_in = replace(measured, range_m=measured.range_m + shift_m)
    held = (to_xyz(measured.range_m, measured.azimuth_rad, measured.factory, offsets)
            - to_xyz(stand_in.range_m, stand_in.azimuth_rad, stand_in.factory, offsets))
    return stand_in, held


def world_points(returns: Returns, offsets: np.ndarray, R_E: np.ndarray, t_E: np.ndarray,
                 corrections: Corrections, jacobians: bool = True,
                 turn: Turn | None = None, held_lidar: np.ndarray | None = None) -> tuple[np.ndarray, WorldJacobians | None]:
    """(N,3) world points [m] and, if asked, their Jacobians. offsets: (N,4) per return; turn:
    Turn.of(corrections, returns.alpha, jacobians) when the caller already has it; held_lidar (N,3)
    [m]: added to eq. 4.2's point in the sensor frame, held fixed (it turns with the sensor, not with
    the intrinsic offsets)."""
    p_l, J_intrinsic = to_xyz_with_jacobian(returns.range_m, returns.azimuth_rad, returns.factory, offsets, jacobians)
    if held_lidar is not None:
        p_l = p_l + held_lidar
    p_b = p_l @ R_E.T + t_E
    q = np.einsum("nij,nj->ni", returns.R_nav, p_b)
    turn = turn or Turn.of(corrections, returns.alpha, jacobians)
    p_w = returns.X_nav + corrections.translation(returns.alpha) + turn.apply(q)
    if not jacobians:
        return p_w, None

    MR_E = turn.after(returns.R_nav, R_E)  # d p_w / d p_l
    intrinsic = MR_E @ J_intrinsic
    extrinsic = np.concatenate([-MR_E @ so3.skew(p_l), MR_E], axis=2)
    aa = returns.alpha[:, None, None]
    if turn.R_w is None:
        eye = np.broadcast_to(np.eye(3), (len(p_w), 3, 3))
        return p_w, WorldJacobians(intrinsic, extrinsic, (1 - aa) * eye, aa * eye)
    d_lo, d_hi = turn.d_rotation(q)
    return p_w, WorldJacobians(intrinsic, extrinsic,
                               np.concatenate([d_lo, (1 - aa) * corrections.rotation_lo], axis=2),
                               np.concatenate([d_hi, aa * corrections.rotation_hi], axis=2))


def world_normals(returns: Returns, R_E: np.ndarray, corrections: Corrections, normal_lidar: np.ndarray,
                  jacobians: bool = True, turn: Turn | None = None) -> tuple[np.ndarray, WorldJacobians | None]:
    """(N,3) unit normals in world axes of normals held in each return's lidar frame, turned by
    the extrinsic rotation, the INS attitude and the rotation correction at its time, so that a
    rigid turn of the cloud turns its normals too (point-to-plane distances stay invariant and
    an unobservable rotation stays unobservable). Jacobians as world_points' (intrinsic zero;
    translation columns zero); turn as in world_points."""
    u = np.einsum("nij,nj->ni", returns.R_nav, normal_lidar @ R_E.T)
    turn = turn or Turn.of(corrections, returns.alpha, jacobians)
    n_w = turn.apply(u)
    if not jacobians:
        return n_w, None
    zeros = np.zeros((len(n_w), 3, 3))
    extrinsic = np.concatenate([-turn.after(returns.R_nav, R_E) @ so3.skew(normal_lidar), zeros], axis=2)
    if turn.R_w is None:
        return n_w, WorldJacobians(np.zeros((len(n_w), 3, 4)), extrinsic, zeros, zeros)
    d_lo, d_hi = turn.d_rotation(u)
    return n_w, WorldJacobians(np.zeros((len(n_w), 3, 4)), extrinsic, np.concatenate([d_lo, zeros], axis=2),
                               np.concatenate([d_hi, zeros], axis=2))


def normals_to_lidar(returns: Returns, R_E: np.ndarray, corrections: Corrections, normal_world: np.ndarray) -> np.ndarray:
    """Inverse of world_normals at the given values: world-axes normals (N,3) -> each return's lidar frame."""
    turn = Turn.of(corrections, returns.alpha, jacobians=False)
    u = normal_world if turn.R_w is None else np.einsum("nji,nj->ni", turn.R_w, normal_world)
    return np.einsum("nji,nj->ni", returns.R_nav, u) @ R_E
