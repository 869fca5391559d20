"""Calibration settings (validated, with defaults that work on the scenarios)."""

from __future__ import annotations

import fnmatch
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from graphcal.calibration.observability import EXTRINSIC_NAMES, INTRINSIC_NAMES
from graphcal.common.errors import ConfigError
from graphcal.recording.range_noise import noisy

Mode = Literal["auto", "intrinsic", "extrinsic", "trajectory", "joint", "joint_trajectory",
               "extrinsic_then_intrinsic", "intrinsic_then_extrinsic"]


# what each single-stage mode estimates: (intrinsics, extrinsic, trajectory)
ESTIMATES = {"intrinsic": (True, False, False), "extrinsic": (False, True, False),
             "trajectory": (False, False, True), "joint": (True, True, False),
             "joint_trajectory": (True, True, True)}
FEATURE_VOXEL_M = 0.1  # static sensors and noisy heads; spans the HDL-32E's rings on walls within ~10 m
# a static sensor's fibres can all slide onto one cone, where every pair's distance vanishes; its range and
# azimuth offsets fit the surfaces between the rings, not the sensor, and a ring's height cannot be told from
# the ground's radial shape (docs/math.md "A static sensor"): everything is held; free Hz with `hold` to try it
STATIC_HOLD = ("fibre_*.d_elevation_deg", "fibre_*.d_range_m", "fibre_*.d_azimuth_deg", "fibre_*.h_z_m")
MAX_FIBRES = 128  # the most fibres of a supported head: the vocabulary of `hold` before the sensor is known
STAGES = {"extrinsic_then_intrinsic": ("extrinsic", "intrinsic"),
          "intrinsic_then_extrinsic": ("intrinsic", "extrinsic")}


class CalibrationConfig(BaseModel):
    """Settings of graphcal.calibrate. Lengths in m, angles in deg, times in s.

    Each stage runs a coarse phase (loose association, the gate opening from gate_start_m to
    gate_max_m) until the largest step falls below fine_below_m, then a fine phase (strict
    association: only clearly planar p and m on the same surface, a fixed gate) until the largest
    step falls below tolerance_m or max_outer_iterations is reached."""

    model_config = ConfigDict(frozen=True, extra="forbid")
    mode: Mode = Field("auto", description=(
        "what to estimate; auto: what a mapping drive needs, intrinsics and extrinsic (joint), plus trajectory "
        "corrections when the drive comes back to where it was (joint_trajectory: only a second pass shows the "
        "trajectory's errors, trajectory_revisits); a static sensor: intrinsic (held by its checks)"))
    max_points: int | None = Field(1_000_000, ge=1000, description=(
        "use a random subset of this many returns (None: all); the pairs per fibre pair are capped "
        "(max_pairs_per_fibre_pair), so more returns mostly sharpen the normals and cost time"))
    neighbours: int = Field(2, ge=1, description="N: fibres j in [i-N, i+N] in elevation order")
    refresh_every: int = Field(2, ge=1, description="K: outer iterations between feature refreshes")
    refresh_above_m: float = Field(0.001, ge=0, description=(
        "features are refreshed (every K iterations) only once some point has moved more than this since they were "
        "computed, the cloud's best rigid motion removed (or that motion turned the normals by more than this over "
        "feature_radius_m): late in the fine phase the cloud's shape changes by fractions of a millimetre"))
    feature_radius_m: float = Field(0.5, gt=0)
    feature_neighbours: int = Field(20, ge=5)
    feature_voxel_m: float | None = Field(None, ge=0, description=(
        "features from the cloud averaged in voxels of this size (0: from every return); None: "
        f"{FEATURE_VOXEL_M} m for a static sensor (it sees the same spots every revolution) or a noisy head "
        "(range_noise_m; normals of 20 returns near the head are mostly noise), else 0"))
    hold: tuple[str, ...] | None = Field(None, description=(
        "parameters held at nominal and named unobservable, e.g. 'fibre_*.d_elevation_deg' (shell wildcards); "
        f"None: {', '.join(STATIC_HOLD)} for a static sensor (docs/math.md \"A static sensor\"), else none"))
    hold_soft: bool | None = Field(None, description=(
        "before solving, also hold the intrinsics that the data at the start (strict association) determine "
        "worse than firm_sigma_m / firm_sigma_deg, alone or in combination (observability.soft_parameters); "
        "None: for a static sensor"))
    firm_sigma_m: float = Field(0.01, gt=0, description="hold_soft: largest 1-sigma of a determined length")
    firm_sigma_deg: float = Field(0.05, gt=0, description="hold_soft: largest 1-sigma of a determined angle")
    check_halves: bool | None = Field(None, description=(
        "before solving, fit the intrinsics on each azimuth half of the scene and hold those whose two estimates "
        "differ by more than 3 firm sigmas (a sensor's offset is the same in every direction); None: for a "
        "static sensor"))
    fixed_association: bool | None = Field(None, description=(
        "pair and estimate normals once, with the strict (fine) settings at the start, and keep them: the energy "
        "is then a plain least-squares fit; None: for a static sensor, whose re-associated energy falls by "
        "dropping pairs and by re-shaping the ground (docs/math.md)"))
    min_planarity: float = Field(0.3, ge=0, le=1, description="coarse phase: p and m both at least this planar")
    max_normal_angle_deg: float = Field(30.0, gt=0, le=90, description="coarse phase: normals at p and m agree within")
    max_plane_distance_m: float = Field(np.inf, gt=0, description="coarse phase: m this close to the plane at p")
    gate_start_m: float = Field(0.3, gt=0, description="association gate at the first iteration")
    gate_max_m: float = Field(1.0, gt=0, description="the gate opens by gate_growth per iteration up to this")
    gate_growth: float = Field(1.2, ge=1)
    fine_below_m: float = Field(0.01, gt=0, description="switch to the fine phase when max |dX| is below")
    fine_min_planarity: float = Field(0.7, ge=0, le=1)
    fine_max_normal_angle_deg: float = Field(10.0, gt=0, le=90)
    fine_max_plane_distance_m: float = Field(0.05, gt=0)
    fine_gate_m: float = Field(0.3, gt=0)
    max_pairs_per_fibre_pair: int = Field(4000, ge=10, description="fine phase: pairs drawn per (i, j) fibre pair")
    coarse_max_points: int | None = Field(250_000, ge=1000, description=(
        "coarse phase: a random subset of this many of the returns used (None: all); features, association and "
        "graph cost in proportion"))
    coarse_pairs_per_fibre_pair: int = Field(1000, ge=10, description=(
        "coarse phase: pairs drawn per (i, j) fibre pair (at most max_pairs_per_fibre_pair); it only has to reach "
        "the basin, the fine phase sets the accuracy"))
    sigma0_m: float = Field(0.01, gt=0, description="nominal point noise: residuals are whitened by it")
    range_noise_m: float | None = Field(None, ge=0, description=(
        "the head's range noise (1-sigma); None: measured from the recording's returns (range_noise.py), and "
        "written here in the results' config.yaml. From 1 mm on (range_noise.NOISY_ABOVE_M) the head is noisy: m "
        "is chosen by the returns' stand-ins, which its noise does not move (below: nearest returns), and "
        "pair_noise and feature_voxel_m left None resolve for it (docs/math.md \"Which m\")"))
    pair_noise: Literal["uniform", "incidence"] | None = Field(None, description=(
        "uniform: every pair's residual whitened by sigma0; incidence: sigma0 is the range noise, which moves a "
        "return along its line of sight u, so pair k's residual n.(p - m) has (sigma0^2 ((n.u_p)^2 + (n.u_m)^2 + "
        "f^2) + s3^2)^1/2 (f = INCIDENCE_FLOOR for the normals' errors; s3 the out-of-plane scatter of p's "
        "neighbourhood, the plane model's error, 0 with fixed_association), in the fine phase: the efficient weighting "
        "when range noise dominates (with feature_voxel_m 0.1, docs/math.md); the reported sigmas then count each "
        "return's noise once over the pairs that share it (calibration/shared_returns.py); None: incidence for a "
        "noisy head (range_noise_m), else uniform"))
    control_interval_s: float = Field(1.0, gt=0)
    block_controls: int = Field(4, ge=1, description="control intervals of p grouped in one block factor")
    pose_corrections: bool = Field(False, description="Pose3 trajectory corrections (else Point3)")
    lambda_rigid: float = Field(1e-6, gt=0, description=(
        "weight of E_def against the normalised energy J (eq. 5.4, both m^2): the seed's 1e2 is against the "
        "un-normalised sum of eq. 5.5 over a full cloud's pairs (weight sum ~1e7), 1e-5 here; 1e-6 measured "
        "better (docs/math.md)"))
    deformation: Literal["prior", "monnier"] = "prior"
    intrinsic_sigma_range_m: float = Field(0.02, gt=0, description=(
        "the nominal model's stated uncertainty (1-sigma) on d_range and Hz, a prior about the nominal 0: a "
        "factory calibration is good to about 2 cm and 0.2 deg; give more for a start known to be further off"))
    intrinsic_sigma_angle_deg: float = Field(0.2, gt=0, description="the same for d_azimuth and d_elevation")
    extrinsic_sigma_lever_arm_m: float = Field(0.1, gt=0, description=(
        "the nominal extrinsic's stated uncertainty (1-sigma) on each lever-arm axis: a tape-measured mounting"))
    extrinsic_sigma_boresight_deg: float = Field(1.0, gt=0, description="the same for each boresight angle")
    max_outer_iterations: int = Field(60, ge=1, description="n_max, per stage (coarse and fine phases together)")
    refuse_unconverged: bool = Field(True, description=(
        "a run whose outer iterations stop on max_outer_iterations before converging ends in CalibrationError "
        "(exit 3), and so does one whose J ends far above what the measured noise predicts; False returns the "
        "estimate unchecked on both counts (a quick look with a small max_outer_iterations)"))
    tolerance_m: float = Field(1e-5, gt=0, description="delta: stop when max |dX| (m, or rad x 1 m) is below")
    plateau_iterations: int = Field(6, ge=2, description=(
        "fine phase: also stop when J has not reached a new low (by plateau_improvement) in this many outer "
        "iterations: the association's jitter can keep max |dX| above tolerance_m at a J that no longer falls"))
    plateau_improvement: float = Field(0.01, ge=0, lt=1, description="relative fall of J that counts as a new low")
    step_sigma_m: float = Field(0.02, gt=0, description="damping of one outer step, lengths")
    step_sigma_deg: float = Field(0.5, gt=0, description="damping of one outer step, angles")
    lm_iterations: int | None = Field(None, ge=1, description=(
        "Levenberg-Marquardt iterations per outer iteration; None: 2 when the association is refreshed (the pairs "
        "change at the next outer iteration, so the inner problem need not be solved to the end: sim6_turn "
        "joint_trajectory full size 5 -> 67 s, 2 -> 48 s with the same accuracy, 1 -> 72 s), 5 on fixed pairs"))
    robust: Literal["none", "huber", "cauchy"] = "none"
    robust_k: float = Field(2.0, gt=0, description="in units of sigma0")
    seed: int = 0

    @field_validator("hold")
    @classmethod
    def _hold_names_parameters(cls, hold: tuple[str, ...] | None) -> tuple[str, ...] | None:
        if hold is not None:
            held_names(hold, MAX_FIBRES, None)
        return hold

    def for_sensor(self, static: bool, range_noise_m: float = np.nan, revisits: bool = False) -> CalibrationConfig:
        """The settings left to the recording (None, mode auto) resolved for a static or a moving sensor whose
        range noise is range_noise_m (as measured when it was not set; NaN: unknown, left as set) and whose
        drive comes back to where it was or not (revisits)."""
        mode = self.mode
        if mode == "auto":
            mode = "intrinsic" if static else ("joint_trajectory" if revisits else "joint")
        noise_m = self.range_noise_m if np.isnan(range_noise_m) else float(range_noise_m)
        noisy_head = noisy(np.nan if noise_m is None else noise_m)
        voxel_m = self.feature_voxel_m
        if voxel_m is None:
            voxel_m = FEATURE_VOXEL_M if static or noisy_head else 0.0
        hold = (STATIC_HOLD if static else ()) if self.hold is None else self.hold
        fixed = static if self.fixed_association is None else self.fixed_association
        return self.model_copy(update={
            "lm_iterations": (5 if fixed else 2) if self.lm_iterations is None else self.lm_iterations,
            "feature_voxel_m": voxel_m, "hold": hold,
            "hold_soft": static if self.hold_soft is None else self.hold_soft,
            "check_halves": static if self.check_halves is None else self.check_halves,
            "fixed_association": fixed, "range_noise_m": noise_m, "mode": mode,
            "pair_noise": self.pair_noise or ("incidence" if noisy_head else "uniform")})

    def coarse(self) -> CalibrationConfig:
        """The settings of the coarse phase: uniform pair noise (far from the solution the residuals are
        the calibration's errors, not the range noise's)."""
        return self.model_copy(update={"max_pairs_per_fibre_pair": min(self.max_pairs_per_fibre_pair,
                                                                       self.coarse_pairs_per_fibre_pair),
                                       "pair_noise": "uniform"})

    def fine(self) -> CalibrationConfig:
        """The settings of the fine phase."""
        return self.model_copy(update={"min_planarity": self.fine_min_planarity,
                                       "max_normal_angle_deg": self.fine_max_normal_angle_deg,
                                       "max_plane_distance_m": self.fine_max_plane_distance_m,
                                       "gate_start_m": self.fine_gate_m, "gate_max_m": self.fine_gate_m})


def held_names(patterns: tuple[str, ...], n_fibres: int, reference_fibre: int | None) -> list[str]:
    """The parameter names of a sensor with n_fibres (the reference fibre's fixed, none if None)
    matched by patterns (shell wildcards, e.g. 'fibre_*.d_elevation_deg'); ConfigError for a pattern
    that names no parameter."""
    names = [f"fibre_{i}.{name}" for i in range(n_fibres) if i != reference_fibre for name in INTRINSIC_NAMES]
    names += [f"extrinsic.{name}" for name in EXTRINSIC_NAMES]
    for pattern in patterns:
        if not fnmatch.filter(names, pattern):
            raise ConfigError(f"{pattern!r} names no parameter (expected e.g. 'fibre_3.d_range_m', "
                              f"'fibre_*.d_elevation_deg', 'extrinsic.lever_arm_z_m')")
    return [name for name in names if any(fnmatch.fnmatchcase(name, pattern) for pattern in patterns)]
