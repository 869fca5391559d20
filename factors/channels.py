"""The channels through which an effect moves a return, and the analytic Jacobian of the world
point along each. Pure NumPy, no I/O.

An effect k (factors.effects, factors.discrepancy) with parameters theta_k (d_k,) moves eight *channels* of each
return, each linearly, channel = B_k theta_k with a per-return basis B_k (its residual signature):

    range       d_rho   [m]    added to the raw range                      (eq. 4.2's rho)
    azimuth     d_theta [rad]  added to the encoder azimuth                (eq. 4.2's theta)
    elevation   d_phi   [rad]  added to the fibre's elevation              (eq. 4.2's phi_i)
    horizontal  d_H     [m]    added to the fibre's horizontal offset H_i (factory terms)
    time        d_t     [s]    added to the return's time: the INS pose is taken at t + d_t
    heading     d_psi   [rad]  turns the INS attitude about world z
    body        d_b     [m]    added to the lever arm (body frame)
    position    d_X     [m]    added to the INS position (world frame)

so that, with v and omega the INS velocity and angular rate at the return's time (world axes),

    R_nav' = Exp(omega d_t) Exp(z d_psi) R_nav,   X_nav' = X_nav + v d_t + d_X,   t_E' = t_E + d_b

and the world point of factors.world_point is evaluated with those. The pose part is exact for a
pose moving at constant velocity and angular rate over d_t. A shift of up to a revolution (0.1 s,
returns stamped with their revolution's start) leaves millimetres in a turn, so the motion can be
taken about a shift t_0 (Motion.about_s) instead, with the exact pose step (S_X, S_R) from t to
t + t_0 and v, omega at t + t_0:

    R_nav' = Exp(omega (d_t - t_0)) S_R Exp(z d_psi) R_nav,   X_nav' = X_nav + S_X + v (d_t - t_0) + d_X,

exact at d_t = t_0 whatever the motion, first order about it.

Jacobians d p_w / d channel, at the perturbed values (M = R_w R_nav' R_E, R_w the trajectory
rotation correction, q the vehicle-to-point vector R_w R_nav' p_b):
    range, azimuth, elevation: the intrinsic Jacobian's d_rho, d_theta, d_phi columns (they enter eq. 4.2
                    the same way)
    horizontal:     M (sin a, cos a, 0),  a = theta + d_theta + alpha_i
    time:           v + (R_w omega) x q           heading: (R_w Exp(omega (d_t - t_0)) S_R z) x q
    body:           R_w R_nav'                    position: I
The normal at p turns with the pose channels: dn/d(time) = (R_w omega) x n, dn/d(heading) = (R_w
Exp(omega (d_t - t_0)) S_R z) x n.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from factors import so3
from factors.world_point import Placed, Returns

SCALAR_CHANNELS = ("range", "azimuth", "elevation", "horizontal", "time", "heading")
VECTOR_CHANNELS = ("body", "position")
Z_AXIS = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class Context:
    """Per-return data (N returns) the candidates' bases are built from: raw range [m] and encoder
    azimuth [rad], fibre id, number of fibres, time within the revolution [s] (azimuth / (2 pi
    nominal rate)), time since the recording's first pose [s], |cos| of the incidence angle, INS
    position X_nav (N,3) [m, world minus the local origin]; and where known, the return's intensity
    (points.parquet's units), the INS speed [m/s] and yaw rate [rad/s, about world z]."""

    range_m: np.ndarray
    azimuth_rad: np.ndarray
    fibre: np.ndarray
    n_fibres: int
    sweep_s: np.ndarray
    elapsed_s: np.ndarray
    cos_incidence: np.ndarray
    X_nav: np.ndarray
    intensity: np.ndarray | None = None
    speed_m_s: np.ndarray | None = None
    yaw_rate_rad_s: np.ndarray | None = None


@dataclass(frozen=True)
class Basis:
    """One candidate's linear map from its parameters (dim,) to the channels of N returns: scalar
    channels (N, dim), vector channels (N, 3, dim); None where the candidate leaves a channel alone."""

    dim: int
    range: np.ndarray | None = None
    azimuth: np.ndarray | None = None
    elevation: np.ndarray | None = None
    horizontal: np.ndarray | None = None
    time: np.ndarray | None = None
    heading: np.ndarray | None = None
    body: np.ndarray | None = None
    position: np.ndarray | None = None


@dataclass(frozen=True)
class Motion:
    """INS velocity (N,3) [m/s] and angular rate (N,3) [rad/s], world axes, at each return's time t + about_s
    (N,) [s], and the INS pose's exact step from t to t + about_s: step_position_m (N,3) [m, world axes] and
    step_rotation (N,3,3), R_nav(t + about_s) = step_rotation R_nav(t). Without about_s (None): about the
    return's own time, no step."""

    velocity: np.ndarray
    omega: np.ndarray
    about_s: np.ndarray | None = None
    step_position_m: np.ndarray | None = None
    step_rotation: np.ndarray | None = None

    def shift(self, time_s: np.ndarray) -> np.ndarray:
        """The time channel's shift (N,) [s] from the time the motion is taken about."""
        return time_s if self.about_s is None else time_s - self.about_s

    def turn(self, time_s: np.ndarray) -> np.ndarray:
        """The attitude's turn (N,3,3) from R_nav(t) to R_nav(t + time_s), heading left aside."""
        turn = so3.exp(self.omega * self.shift(time_s)[:, None])
        return turn if self.step_rotation is None else turn @ self.step_rotation

    def step(self, time_s: np.ndarray) -> np.ndarray:
        """The position's step (N,3) [m] from X_nav(t) to X_nav(t + time_s)."""
        step = self.velocity * self.shift(time_s)[:, None]
        return step if self.step_position_m is None else step + self.step_position_m


@dataclass(frozen=True)
class Channels:
    """The channel values of N returns for given candidate parameters (see the module docstring)."""

    range: np.ndarray
    azimuth: np.ndarray
    elevation: np.ndarray
    horizontal: np.ndarray
    time: np.ndarray
    heading: np.ndarray
    body: np.ndarray
    position: np.ndarray

    @classmethod
    def of(cls, bases: tuple[Basis, ...], thetas: list[np.ndarray], n: int) -> Channels:
        values = {name: np.zeros(n) for name in SCALAR_CHANNELS} | {name: np.zeros((n, 3)) for name in VECTOR_CHANNELS}
        for basis, theta in zip(bases, thetas):
            for name in SCALAR_CHANNELS + VECTOR_CHANNELS:
                B = getattr(basis, name)
                if B is not None:
                    values[name] = values[name] + B @ np.asarray(theta, dtype=np.float64)
        return cls(**values)


def perturbed(returns: Returns, motion: Motion, channels: Channels) -> Returns:
    """The returns with their channels applied: raw range and azimuth, elevations, horizontal offsets, INS pose."""
    factory = replace(returns.factory, elevation_rad=returns.factory.elevation_rad + channels.elevation,
                      horizontal_offset_m=returns.factory.horizontal_offset_m + channels.horizontal)
    turn = motion.turn(channels.time) @ so3.exp(Z_AXIS * channels.heading[:, None])
    return replace(returns, range_m=returns.range_m + channels.range, azimuth_rad=returns.azimuth_rad + channels.azimuth,
                   factory=factory, R_nav=turn @ returns.R_nav,
                   X_nav=returns.X_nav + motion.step(channels.time) + channels.position)


@dataclass(frozen=True)
class ChannelJacobians:
    """d p_w / d channel (N,3) for scalar channels, (N,3,3) for vector ones, and d n_w / d channel for
    the two that turn the normal (time, heading; (N,3))."""

    point: dict
    normal_time: np.ndarray
    normal_heading: np.ndarray

    def of_candidate(self, basis: Basis) -> np.ndarray:
        """d p_w / d theta (N, 3, dim) of one candidate."""
        total = 0.0
        for name in SCALAR_CHANNELS:
            B = getattr(basis, name)
            if B is not None:
                total = total + self.point[name][:, :, None] * B[:, None, :]
        for name in VECTOR_CHANNELS:
            B = getattr(basis, name)
            if B is not None:
                total = total + self.point[name] @ B
        return total

    def normal_of_candidate(self, basis: Basis) -> np.ndarray | None:
        """d n_w / d theta (N, 3, dim), or None when the candidate does not turn the normal."""
        parts = [J[:, :, None] * B[:, None, :] for J, B in ((self.normal_time, basis.time),
                                                           (self.normal_heading, basis.heading)) if B is not None]
        return sum(parts) if parts else None


def channel_jacobians(placed: Placed, motion: Motion, channels: Channels,
                      n_w: np.ndarray | None = None) -> ChannelJacobians:
    """Channel Jacobians at the perturbed returns (placed.returns = perturbed(...)), placed in the world by
    world_points; the normal n_w (N,3) from world_normals (None: no normal Jacobians)."""
    returns, offsets, corrections, turn = placed.returns, placed.offsets, placed.corrections, placed.turn
    p_w, J, R_E = placed.points_w, placed.J, placed.R_E
    M = J.extrinsic[:, :, 3:6]  # d p_w / d t_E in lidar axes = R_w R_nav' R_E
    a = returns.azimuth_rad + offsets[:, 1] + returns.factory.azimuth_offset_rad
    sideways = np.stack([np.sin(a), np.cos(a), np.zeros_like(a)], axis=-1)
    q = p_w - returns.X_nav - corrections.translation(returns.alpha)
    omega = turn.apply(motion.omega)
    z = turn.apply(np.einsum("nij,j->ni", motion.turn(channels.time), Z_AXIS))
    body = M @ R_E.T
    point = {"range": J.intrinsic[:, :, 0], "azimuth": J.intrinsic[:, :, 1], "elevation": J.intrinsic[:, :, 2],
             "horizontal": np.einsum("nij,nj->ni", M, sideways), "time": motion.velocity + np.cross(omega, q),
             "heading": np.cross(z, q), "body": body,
             "position": np.broadcast_to(np.eye(3), (len(p_w), 3, 3))}
    if n_w is None:
        return ChannelJacobians(point, None, None)
    return ChannelJacobians(point, np.cross(omega, n_w), np.cross(z, n_w))
