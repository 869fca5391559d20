"""The priors of a calibration: the nominal model's stated uncertainty on the intrinsics and the
extrinsic (config.priors), E_def on the trajectory corrections (eq. 5.3/5.4), and what is held at its
nominal value (a prior of HELD_SIGMA)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import gtsam
import numpy as np

from graphcal.calibration.config import CalibrationConfig
from graphcal.calibration.observability import parameter_at, tangent_to_axes
from graphcal.calibration.returns import Estimate

HELD_SIGMA = 1e-7  # prior sigma (m or rad) that holds a parameter at its nominal value


@dataclass(frozen=True)
class Priors:
    """Prior 1-sigmas about the nominal values, SI (m, rad): intrinsics (n_fibres, 4); extrinsic
    (6,) rotation then lever arm, both in body axes; control_held (C, 3 or 6) marks control
    components held at zero (their other prior is E_def, set from the weight sum)."""

    intrinsic: np.ndarray
    extrinsic: np.ndarray
    control_held: np.ndarray

    @classmethod
    def of(cls, config: CalibrationConfig, n_fibres: int, n_controls: int) -> Priors:
        stated = config.priors
        angle = np.radians(stated.intrinsic_angle_deg)
        one = np.r_[stated.intrinsic_range_m, angle, angle, stated.intrinsic_range_m]
        extrinsic = np.r_[np.full(3, np.radians(stated.extrinsic_boresight_deg)), np.full(3, stated.extrinsic_lever_arm_m)]
        return cls(np.tile(one, (n_fibres, 1)), extrinsic,
                   np.zeros((n_controls, 6 if config.trajectory.pose_corrections else 3), bool))

    def extrinsic_noise(self, R_body_lidar: np.ndarray):
        """Gaussian noise on the Pose3 tangent [w, v] (lidar axes) for body-axes sigmas."""
        to_tangent = tangent_to_axes(R_body_lidar).T
        return gtsam.noiseModel.Gaussian.Covariance(to_tangent @ np.diag(self.extrinsic ** 2) @ to_tangent.T)

    def holding(self, names: list[str]) -> Priors:
        """These priors with the named parameters' sigmas shrunk to HELD_SIGMA (held at nominal)."""
        intrinsic, extrinsic, control = self.intrinsic.copy(), self.extrinsic.copy(), self.control_held.copy()
        for name in names:
            group, row, column = parameter_at(name)
            if group == "intrinsics":
                intrinsic[row, column] = HELD_SIGMA
            elif group == "extrinsic":
                extrinsic[column] = HELD_SIGMA
            else:  # translation-only controls have no rotation columns
                control[row, column - (6 - control.shape[1])] = True
        return replace(self, intrinsic=intrinsic, extrinsic=extrinsic, control_held=control)

    def free_intrinsics(self, fixed_fibre: int | None) -> np.ndarray:
        """(n_fibres, 4) True where an intrinsic is estimated: not held, not the fixed fibre's (the reference,
        PriorSettings.fixed_fibre)."""
        free = self.intrinsic > HELD_SIGMA
        if fixed_fibre is not None:
            free[fixed_fibre] = False
        return free

    def hold_at_nominal(self, estimate: Estimate, nominal_extrinsic: gtsam.Pose3) -> Estimate:
        """The estimate with every held parameter set back to nominal."""
        offsets = np.where(self.intrinsic <= HELD_SIGMA, 0.0, estimate.offsets)
        held_ext = self.extrinsic <= HELD_SIGMA
        extrinsic = estimate.extrinsic
        if held_ext.any():
            to_body = tangent_to_axes(nominal_extrinsic.rotation().matrix())
            body = to_body @ nominal_extrinsic.localCoordinates(estimate.extrinsic)
            body[held_ext] = 0.0
            extrinsic = nominal_extrinsic.retract(to_body.T @ body)
        corrections = tuple(_zero_components(c, held) for c, held in zip(estimate.corrections, self.control_held))
        return replace(estimate, offsets=offsets, extrinsic=extrinsic, corrections=corrections)


def control_prior_sigma(config: CalibrationConfig, weight_sum: float) -> float:
    """sigma [m, or rad x 1 m] of E_def's prior on each control correction: eq. 5.4 adds
    lambda_rigid |dX|^2 to the normalised energy J [m^2], and the graph's cost is W J / sigma0^2
    (W the weight sum of the pairs)."""
    return config.weighting.sigma0_m / np.sqrt(config.trajectory.lambda_rigid * max(weight_sum, 1.0))


def _zero_components(correction: gtsam.Pose3, held: np.ndarray) -> gtsam.Pose3:
    if not held.any():
        return correction
    tangent = np.r_[gtsam.Rot3.Logmap(correction.rotation()), correction.translation()]
    tangent[-len(held):][held] = 0.0
    return gtsam.Pose3(gtsam.Rot3.Expmap(tangent[:3]), tangent[3:])
