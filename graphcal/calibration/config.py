"""Calibration settings (validated, with defaults that work on the scenarios)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

Mode = Literal["intrinsic", "extrinsic", "trajectory", "joint", "joint_trajectory",
               "extrinsic_then_intrinsic", "intrinsic_then_extrinsic"]

# what each single-stage mode estimates: (intrinsics, extrinsic, trajectory)
ESTIMATES = {"intrinsic": (True, False, False), "extrinsic": (False, True, False),
             "trajectory": (False, False, True), "joint": (True, True, False),
             "joint_trajectory": (True, True, True)}
STAGES = {"extrinsic_then_intrinsic": ("extrinsic", "intrinsic"),
          "intrinsic_then_extrinsic": ("intrinsic", "extrinsic")}


class CalibrationConfig(BaseModel):
    """Settings of graphcal.calibrate. Lengths in m, angles in deg, times in s."""

    model_config = ConfigDict(frozen=True, extra="forbid")
    mode: Mode = "intrinsic"
    neighbours: int = Field(2, ge=1, description="N: fibres j in [i-N, i+N] in elevation order")
    refresh_every: int = Field(7, ge=1, description="K: outer iterations between feature refreshes")
    feature_radius_m: float = Field(0.5, gt=0)
    feature_neighbours: int = Field(20, ge=5)
    min_planarity: float = Field(0.3, ge=0, le=1)
    gate_start_m: float = Field(0.3, gt=0, description="association gate at the first iteration")
    gate_max_m: float = Field(1.0, gt=0, description="the gate opens by gate_growth per iteration up to this")
    gate_growth: float = Field(1.2, ge=1)
    max_pairs_per_fibre_pair: int = Field(4000, ge=10)
    sigma0_m: float = Field(0.01, gt=0, description="nominal point noise: residuals are whitened by it")
    control_interval_s: float = Field(1.0, gt=0)
    pose_corrections: bool = Field(False, description="Pose3 trajectory corrections (else Point3)")
    lambda_rigid: float = Field(1.0, gt=0, description="weight of E_def (eq. 5.1), per m^2 of correction")
    deformation: Literal["prior", "monnier"] = "prior"
    extrinsic_sigma_lever_arm_m: float = Field(1.0, gt=0)
    extrinsic_sigma_boresight_deg: float = Field(10.0, gt=0)
    max_outer_iterations: int = Field(30, ge=1, description="n_max")
    tolerance_m: float = Field(1e-5, gt=0, description="delta: stop when max |dX| (m, or rad x 1 m) is below")
    lm_iterations: int = Field(5, ge=1)
    robust: Literal["none", "huber", "cauchy"] = "none"
    robust_k: float = Field(2.0, gt=0, description="in units of sigma0")
    seed: int = 0
