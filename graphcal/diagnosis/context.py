"""What the candidate effects need to know about every return besides the calibration's data: time
within the revolution, time since the first pose, incidence angle, and the INS motion."""

from __future__ import annotations

from dataclasses import dataclass, replace

import gtsam
import numpy as np

from factors.channels import Basis, Channels, Context, Motion, perturbed
from factors.effects import candidate
from factors.point_to_plane import EffectTerms
from factors.world_point import world_points
from graphcal.calibration.association import Features, Sight
from graphcal.calibration.returns import Estimate, ReturnData, corrections_at, world_at
from graphcal.recording.poses import PoseTrack

K = gtsam.symbol_shorthand.K  # candidate effect parameters, Vector


def ins_motion(poses: PoseTrack, time_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """INS velocity [m/s] and angular rate [rad/s], world axes, at times (M,): those of the pose
    interval each time falls in (the derivative of the linear / SLERP interpolation)."""
    dt = np.diff(poses.time)
    velocity = np.diff(poses.position_m, axis=0) / dt[:, None]
    omega = (poses.rotation[1:] * poses.rotation[:-1].inv()).as_rotvec() / dt[:, None]
    index = np.clip(np.searchsorted(poses.time, time_s, side="right") - 1, 0, len(dt) - 1)
    return velocity[index], omega[index]


@dataclass(frozen=True)
class ReturnContext:
    """Per-return arrays (N, the rows of a ReturnData) for the candidates' bases and motion. range_m [m]: the
    range the bases are built from, each return's stand-in range where it has one (association.Sight), not its
    measured range: a basis of the measured range carries the return's own range noise, which is also in its
    residual, and a curve of the range steep where the returns are dense (the ground ring of a downward fibre)
    then gains on held-out data by fitting noise against itself (measured: a clean recording discovered an
    elevation-against-range curve of 1.2 deg peak to peak at 3-7 m)."""

    data: ReturnData
    poses: PoseTrack
    range_m: np.ndarray
    sweep_s: np.ndarray
    elapsed_s: np.ndarray
    cos_incidence: np.ndarray
    velocity: np.ndarray
    omega: np.ndarray
    intensity: np.ndarray | None = None

    @classmethod
    def of(cls, data: ReturnData, poses: PoseTrack, points_m: np.ndarray, features: Features,
           t_E: np.ndarray, sight: Sight | None, intensity: np.ndarray | None = None) -> ReturnContext:
        """points_m: world points (N,3) minus data.origin_m at the current estimate, features their local
        normals; t_E the lever arm [m] (the beam starts at X_nav + R_nav t_E); sight: the returns' stand-ins
        there (returns.sight_at; None: the measured ranges stand for themselves); intensity: each return's
        (points.parquet's units; None: not recorded)."""
        velocity, omega = ins_motion(poses, data.time_s)
        beam = points_m - data.X_nav - np.einsum("nij,j->ni", data.R_nav, t_E)
        beam /= np.maximum(np.linalg.norm(beam, axis=1, keepdims=True), 1e-9)
        cos_incidence = np.clip(np.abs(np.einsum("ni,ni->n", beam, features.normal)), 0.0, 1.0)
        range_m = data.range_m if sight is None else data.range_m + sight.shift_m
        return cls(data, poses, range_m, data.azimuth_rad / (2 * np.pi * data.sensor.rotation_hz),
                   data.time_s - poses.span[0], cos_incidence, velocity, omega, intensity)

    def context(self, rows: np.ndarray) -> Context:
        d = self.data
        return Context(self.range_m[rows], d.azimuth_rad[rows], d.fibre[rows], d.sensor.n_fibres, self.sweep_s[rows],
                       self.elapsed_s[rows], self.cos_incidence[rows], d.X_nav[rows],
                       None if self.intensity is None else self.intensity[rows],
                       np.linalg.norm(self.velocity[rows], axis=1), self.omega[rows, 2])

    def motion(self, rows: np.ndarray, shift_s: np.ndarray | None = None) -> Motion:
        """The INS motion at the returns of rows, taken about their times shifted by shift_s (M,) [s] (the time
        channel's current value; None or zero: their own times): the poses interpolated at the shifted times
        (within the poses' span), so that a shift of up to a revolution moves a return along the drive's own
        path, not along the motion at its stamp held over the shift (factors.channels)."""
        if shift_s is None or not np.any(shift_s):
            return Motion(self.velocity[rows], self.omega[rows])
        time_s = self.data.time_s[rows]
        shifted_s = np.clip(time_s + shift_s, *self.poses.span)
        position_m, rotation = self.poses.interpolate(time_s)
        shifted_position_m, shifted_rotation = self.poses.interpolate(shifted_s)
        velocity, omega = ins_motion(self.poses, shifted_s)
        return Motion(velocity, omega, shifted_s - time_s, shifted_position_m - position_m,
                      (shifted_rotation * rotation.inv()).as_matrix())


@dataclass(frozen=True)
class EffectModel:
    """Candidate effects in a calibration problem's graph (graphcal.calibration.problem.Problem's `effects`):
    their names (key K(i) for the i-th), current values, and prior sigmas (None: no prior, e.g. for a score
    test that only linearises)."""

    names: tuple[str, ...]
    values: dict
    context: ReturnContext
    prior_sigma: dict | None = None

    @property
    def keys(self) -> tuple[int, ...]:
        return tuple(K(i) for i in range(len(self.names)))

    def dim(self, name: str) -> int:
        return candidate(name).dim(self.context.data.sensor.n_fibres)

    def terms(self, p_rows: np.ndarray, m_rows: np.ndarray) -> EffectTerms:
        """The effects' bases and motion over a block's returns p_rows and m_rows, the motion taken about the
        time channel's value at the model's values."""
        p_bases, m_bases = self.bases(p_rows), self.bases(m_rows)
        return EffectTerms(self.keys, p_bases, self.motion(p_rows, p_bases), m_bases, self.motion(m_rows, m_bases))

    def bases(self, rows: np.ndarray) -> tuple[Basis, ...]:
        """Each effect's basis over the returns of rows."""
        context = self.context.context(rows)
        return tuple(candidate(name).basis(context) for name in self.names)

    def channels(self, rows: np.ndarray, bases: tuple[Basis, ...]) -> Channels:
        """The channels of the returns of rows (their bases) at the model's values (zero where it has none)."""
        thetas = [self.values.get(name, np.zeros(self.dim(name))) for name in self.names]
        return Channels.of(bases, thetas, len(rows))

    def motion(self, rows: np.ndarray, bases: tuple[Basis, ...]) -> Motion:
        """The INS motion at the returns of rows, taken about the time channel's value at the model's values."""
        return self.context.motion(rows, self.channels(rows, bases).time)

    def add_to(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> None:
        for key, name in zip(self.keys, self.names):
            value = np.asarray(self.values.get(name, np.zeros(self.dim(name))), dtype=np.float64)
            values.insert(key, value)
            if self.prior_sigma is not None:
                graph.add(gtsam.PriorFactorVector(key, np.zeros(len(value)),
                                                  gtsam.noiseModel.Isotropic.Sigma(len(value), self.prior_sigma[name])))

    def read(self, values: gtsam.Values) -> dict:
        """The effects' values held in solved values."""
        return {name: np.array(values.atVector(key)) for key, name in zip(self.keys, self.names)}

    def with_values(self, values: dict) -> EffectModel:
        """The model with some effects' values replaced (an estimate's)."""
        return replace(self, values={**self.values, **values}) if values else self

    def world(self, data: ReturnData, estimate: Estimate, pose: bool, rows: np.ndarray | None = None) -> np.ndarray:
        """World points [m] of the given returns (all if None) at the estimate, the effects at the estimate's values
        (else the model's)."""
        return world_with_effects(data, estimate, pose, self.with_values(estimate.effects), rows)


def world_with_effects(data: ReturnData, estimate: Estimate, pose: bool, model: EffectModel | None,
                       rows: np.ndarray | None = None) -> np.ndarray:
    """world_at (graphcal.calibration.returns) with the model's effects at their current values."""
    if model is None or not model.names:
        return world_at(data, estimate, pose, rows)
    rows = np.arange(len(data.time_s)) if rows is None else rows
    bases = model.bases(rows)
    channels = model.channels(rows, bases)
    returns = perturbed(data.returns(rows), model.context.motion(rows, channels.time), channels)
    R_E, t_E = estimate.extrinsic.rotation().matrix(), estimate.extrinsic.translation()
    p, _ = world_points(returns, estimate.offsets[data.fibre[rows]], R_E, t_E + channels.body,
                        corrections_at(estimate, data.control[rows], pose), jacobians=False)
    return p
