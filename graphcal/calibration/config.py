"""Calibration settings: one validated model of nested sections (association and its two phases,
features, weighting, priors, trajectory, stopping, static sensor), with defaults for a mapping drive.

Lengths in m, angles in deg, times in s. Each stage runs a coarse phase (loose association, the gate
opening from gate_start_m to gate_max_m) until its step falls below stopping.fine_below_m, then a
fine phase (strict association: only clearly planar p and m on the same surface, a fixed gate) until the
largest step falls below stopping.tolerance_m, J stops falling, or stopping.max_outer_iterations is
reached. A settings file of the former flat layout is refused with the section each field moved to."""

from __future__ import annotations

import fnmatch
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from graphcal.calibration.observability import EXTRINSIC_NAMES, INTRINSIC_NAMES
from graphcal.common.errors import ConfigError
from graphcal.recording.range_noise import noisy

Mode = Literal["auto", "intrinsic", "extrinsic", "trajectory", "joint", "joint_trajectory",
               "extrinsic_then_intrinsic", "intrinsic_then_extrinsic"]
Phase = Literal["coarse", "fine"]

# what each single-stage mode estimates: (intrinsics, extrinsic, trajectory)
ESTIMATES = {"intrinsic": (True, False, False), "extrinsic": (False, True, False),
             "trajectory": (False, False, True), "joint": (True, True, False),
             "joint_trajectory": (True, True, True)}
STAGES = {"extrinsic_then_intrinsic": ("extrinsic", "intrinsic"),
          "intrinsic_then_extrinsic": ("intrinsic", "extrinsic")}


def estimated_by(mode: str) -> tuple[bool, bool, bool]:
    """(intrinsics, extrinsic, trajectory): what a mode other than auto estimates over its stages."""
    return tuple(any(ESTIMATES[stage][k] for stage in STAGES.get(mode, (mode,))) for k in range(3))


FEATURE_VOXEL_M = 0.1  # static sensors and noisy heads; spans the HDL-32E's rings on walls within ~10 m
# a static sensor's fibres can all slide onto one cone, where every pair's distance vanishes; its range and
# azimuth offsets fit the surfaces between the rings, not the sensor, and a ring's height cannot be told from
# the ground's radial shape (docs/reference/math.md "A static sensor"): everything is held; free Hz with `hold`
STATIC_HOLD = ("fibre_*.d_elevation_deg", "fibre_*.d_range_m", "fibre_*.d_azimuth_deg", "fibre_*.h_z_m")
MAX_FIBRES = 128  # the most fibres of a supported head: the vocabulary of `hold` before the sensor is known

_SECTION = ConfigDict(frozen=True, extra="forbid")


class PhaseGates(BaseModel):
    """What a pair of one phase must pass, and how many are drawn: p and m both at least min_planarity
    planar, their normals within max_normal_angle_deg, m within max_plane_distance_m of the plane at p (None, the
    coarse phase's default: COARSE_PLANE_DISTANCE_M with the trajectory held, none with it estimated) and
    within the gate of p (opening from gate_start_m by gate_growth per outer iteration up to gate_max_m);
    pairs_per_fibre_pair drawn per (i, j) fibre pair; the phase's returns, a random subset of max_points
    of the calibration's (None: all)."""

    model_config = _SECTION
    min_planarity: float = Field(ge=0, le=1)
    max_normal_angle_deg: float = Field(gt=0, le=90)
    max_plane_distance_m: float | None = Field(gt=0)
    gate_start_m: float = Field(gt=0)
    gate_max_m: float = Field(gt=0)
    gate_growth: float = Field(ge=1)
    pairs_per_fibre_pair: int = Field(ge=10)
    max_points: int | None = Field(None, ge=1000)


# with the trajectory held, the coarse gate opens to find partners further along a surface, not across one: m within
# this of the plane at p [m] (without it, J of a level head's 15 s on a street with relief rose from 5.6 to 19.9 cm² as
# the gate opened to 1 m, pairs between a facade and the balconies before it, and the fine phase started from J
# 1.28 cm² instead of 0.79); trajectory corrections must pair across an INS's steps, tens of centimetres, so none then
COARSE_PLANE_DISTANCE_M = 0.2
COARSE = PhaseGates(min_planarity=0.3, max_normal_angle_deg=30.0, max_plane_distance_m=None, gate_start_m=0.3,
                    gate_max_m=1.0, gate_growth=1.2, pairs_per_fibre_pair=1000, max_points=250_000)
# the fine phase's pairs per fibre pair: a level head's weakest fibres (the ground's first rings, the upward ones over
# low houses) are known only as well as these pairs show them; measured on the foreign suburb's level head, 15 s at
# 3.6 M returns: 4000 named 33 of its 126 intrinsic parameters in 175 s, 8000 26 in 234 s, 12 000 25 in 281 s
FINE = PhaseGates(min_planarity=0.7, max_normal_angle_deg=10.0, max_plane_distance_m=0.05, gate_start_m=0.3,
                  gate_max_m=0.3, gate_growth=1.0, pairs_per_fibre_pair=8000)


class AssociationSettings(BaseModel):
    """Which fibres pair (neighbours: j in [i-N, i+N] in elevation order), the gates of the coarse phase
    (it only has to reach the basin; the fine phase sets the accuracy) and of the fine phase, and fixed:
    pair and estimate normals once, at the start with the fine gates, and keep them (the energy is then a
    plain least-squares fit; None: for a static sensor, whose re-associated energy falls by dropping pairs
    and re-shaping the ground); tile_m: features and pairs computed tile by tile of tile_m [m] of the plan
    (graphcal.calibration.tiles; what a Dask cluster spreads; None: the whole cloud at once); moving_sigmas:
    a pair is dropped as seen on a moving object when its residual at the current estimate departs from the
    median of its fibre pair's by more than moving_sigmas robust sigmas (1.4826 MAD, at least
    MOVING_FLOOR_M) and its two returns were acquired far enough apart for an object at moving_speed_m_s
    [m/s] to have moved that far (None, the default: keep every pair, the fine gates keep moving surfaces
    out; graphcal.calibration.moving)."""

    model_config = _SECTION
    neighbours: int = Field(2, ge=1)
    coarse: PhaseGates = COARSE
    fine: PhaseGates = FINE
    fixed: bool | None = None
    tile_m: float | None = Field(None, ge=10.0)
    moving_sigmas: float | None = Field(None, gt=0)
    moving_speed_m_s: float = Field(20.0, gt=0)

    @model_validator(mode="before")
    @classmethod
    def _phases_from_their_defaults(cls, data):
        """A phase given in part (a settings file naming one of its gates) keeps that phase's other defaults."""
        if isinstance(data, dict):
            data = dict(data)
            for phase, default in (("coarse", COARSE), ("fine", FINE)):
                if isinstance(data.get(phase), dict):
                    data[phase] = {**default.model_dump(), **data[phase]}
        return data

    @model_validator(mode="after")
    def _fine_plane_distance_given(self):
        if self.fine.max_plane_distance_m is None:
            raise ValueError("association.fine.max_plane_distance_m: expected a distance in m (null, chosen by the "
                             "mode, is the coarse phase's only)")
        return self


class FeatureSettings(BaseModel):
    """Normals and planarity from the neighbours (at most `neighbours` within radius_m) of each return, or
    of the cloud averaged in voxels of voxel_m (0: every return's; None: FEATURE_VOXEL_M for a static sensor,
    which sees the same spots every revolution, or a noisy head, whose normals of 20 returns near it are
    mostly noise; else 0); refreshed every refresh_every outer iterations once some point has moved more
    than refresh_above_m since they were computed (the cloud's best rigid motion removed)."""

    model_config = _SECTION
    radius_m: float = Field(0.5, gt=0)
    neighbours: int = Field(20, ge=5)
    voxel_m: float | None = Field(None, ge=0)
    refresh_every: int = Field(2, ge=1)
    refresh_above_m: float = Field(0.001, ge=0)


class WeightingSettings(BaseModel):
    """How each pair's residual is whitened: sigma0_m, the nominal point noise; range_noise_m, the head's
    range noise (None: measured from the recording, recording/range_noise.py; from 1 mm on the head is
    noisy: m chosen by stand-ins, features from voxels); pair_noise: uniform (sigma0 for every pair) or
    incidence (the range noise along the pair's two lines of sight, the plane model's error and the
    trajectory's jitter, fine phase only; None: incidence for a noisy head); a robust loss in units of
    sigma0 (robust_k)."""

    model_config = _SECTION
    sigma0_m: float = Field(0.01, gt=0)
    range_noise_m: float | None = Field(None, ge=0)
    pair_noise: Literal["uniform", "incidence"] | None = None
    robust: Literal["none", "huber", "cauchy"] = "none"
    robust_k: float = Field(2.0, gt=0)


class PriorSettings(BaseModel):
    """The nominal model's stated uncertainty (1-sigma), a prior about it: a factory calibration is good to
    about 2 cm and 0.2 deg per fibre, a tape-measured mounting to about 10 cm and 1 deg; give more for a
    start known to be further off."""

    model_config = _SECTION
    intrinsic_range_m: float = Field(0.02, gt=0, description="d_range and Hz")
    intrinsic_angle_deg: float = Field(0.2, gt=0, description="d_azimuth and d_elevation")
    reference_fibre: Literal["fixed", "range_elevation"] = Field(
        "range_elevation", description="range_elevation: the reference fibre's range and elevation offsets estimated "
                                       "under the priors above (a factory model is off there as on the other fibres), "
                                       "its azimuth and height held (the gauges: the boresight's yaw and the lever "
                                       "arm's z); fixed: its four offsets held at nominal (the seed's gauge, for a "
                                       "reference fibre known exact)")
    extrinsic_lever_arm_m: float = Field(0.1, gt=0, description="each lever-arm axis")
    extrinsic_boresight_deg: float = Field(1.0, gt=0, description="each boresight angle")

    def fixed_fibre(self, reference_fibre: int) -> int | None:
        """The fibre whose offsets are all held (no key in the graph): the reference, or None when its range and
        elevation are estimated."""
        return reference_fibre if self.reference_fibre == "fixed" else None

    def gauges(self, reference_fibre: int) -> list[str]:
        """The reference fibre's offsets held as the gauge when the others are estimated (none when it is fixed)."""
        return [] if self.reference_fibre == "fixed" else [f"fibre_{reference_fibre}.d_azimuth_deg",
                                                           f"fibre_{reference_fibre}.h_z_m"]


# the field of AccuracySettings that each intrinsic kind and each extrinsic axis must meet
ACCURACY_FIELDS = {"d_range_m": "intrinsic_range_m", "d_azimuth_deg": "intrinsic_angle_deg",
                   "d_elevation_deg": "intrinsic_angle_deg", "h_z_m": "intrinsic_range_m",
                   **{axis: "extrinsic_boresight_deg" for axis in EXTRINSIC_NAMES[:3]},
                   **{axis: "extrinsic_lever_arm_m" for axis in EXTRINSIC_NAMES[3:]}}


class AccuracySettings(BaseModel):
    """The 1-sigma each intrinsic parameter and each extrinsic axis must reach to count as determined (a mapping
    team's figures: 0.5 cm in range and height, 0.01 deg in azimuth and elevation; 1 cm for the lever arm, 0.01 deg
    for the boresight, which at 50 m moves a point by 0.9 cm). One the drive determines only more coarsely is named
    imprecise (accuracy.py), with its sigma in the reason; unlike an unobservable one it keeps its fitted value,
    which is exported (the data do determine it). None: no such naming for that kind."""

    model_config = _SECTION
    intrinsic_range_m: float | None = Field(0.005, gt=0, description="d_range and Hz")
    intrinsic_angle_deg: float | None = Field(0.01, gt=0, description="d_azimuth and d_elevation")
    extrinsic_lever_arm_m: float | None = Field(0.01, gt=0, description="each lever-arm axis")
    extrinsic_boresight_deg: float | None = Field(0.01, gt=0, description="each boresight angle")

    def required(self, names: tuple[str, ...] = INTRINSIC_NAMES) -> np.ndarray:
        """(len(names),) the required 1-sigma per intrinsic kind or extrinsic axis in file units (m, deg); inf
        where None."""
        values = (getattr(self, ACCURACY_FIELDS[name]) for name in names)
        return np.array([np.inf if v is None else v for v in values])


class TrajectorySettings(BaseModel):
    """Trajectory corrections at control times control_interval_s apart (seed 001: about 1 s), Point3 or
    Pose3 (pose_corrections), held by E_def (eq. 5.4: lambda_rigid against the normalised energy J, both m^2):
    deformation "monnier" (the default) penalises the differences of successive corrections, quadratic up to
    problem.JUMP_HUBER sigmas and linear beyond (an INS's error drifts, with a GNSS update's steps), and each
    correction with sqrt(number of controls) times their sigma (the drive's mean); "prior" each correction (eq.
    5.3), which pulls every stretch the data barely see back to the INS's value (on an hour's drive, the
    along-track corrections of its straight streets); block_controls control intervals of p per block factor;
    coarse_max_controls: the coarse phase corrects the trajectory at every k-th control only (the others
    interpolated between them), k the least that leaves at most this many (None: at every control). On a long drive
    whose passes tie most controls together, the elimination of a solve grows about as the cube of the controls;
    the coarse phase only has to reach the basin."""

    model_config = _SECTION
    control_interval_s: float = Field(1.0, gt=0)
    coarse_max_controls: int | None = Field(300, ge=2)
    block_controls: int = Field(4, ge=1)
    pose_corrections: bool = False
    lambda_rigid: float = Field(1e-5, gt=0)
    deformation: Literal["prior", "monnier"] = "monnier"


class StoppingSettings(BaseModel):
    """The outer loop: at most max_outer_iterations per stage (both phases); the fine phase from a coarse
    step below fine_below_m (the largest over the intrinsics and the extrinsic, the median over the trajectory's
    controls: problem.step_size); converged when the largest step (m, or rad x 1 m) falls below tolerance_m or J
    makes no new low (by plateau_improvement) in plateau_iterations and its last plateau_iterations estimates no
    longer drift (problem.drifting: per kind of parameter, the median move across them below trend_sigmas of the
    parameters' sigmas; J is flat along a weak direction a fit still converges along); each outer step damped by
    a prior at the current estimate (step_sigma_m, step_sigma_deg); lm_iterations Levenberg-Marquardt iterations
    per outer iteration (None: 2 when the pairs are re-made, 5 on fixed pairs); refuse_unconverged: a run that stops on
    the cap, or whose J ends far above what the measured noise predicts, ends in CalibrationError (exit 3)
    (False: the estimate is returned unchecked on both counts, for a quick look); refuse_outside_priors: so does
    one that leaves a parameter far outside the nominal model's stated uncertainty (False: graphcal.diagnose's
    baseline, where such a slide is what a left-out effect does, and is reported)."""

    model_config = _SECTION
    max_outer_iterations: int = Field(60, ge=1)
    tolerance_m: float = Field(1e-5, gt=0)
    fine_below_m: float = Field(0.01, gt=0)
    plateau_iterations: int = Field(6, ge=2)
    plateau_improvement: float = Field(0.01, ge=0, lt=1)
    trend_sigmas: float = Field(2.0, gt=0)
    step_sigma_m: float = Field(0.02, gt=0)
    step_sigma_deg: float = Field(0.5, gt=0)
    lm_iterations: int | None = Field(None, ge=1)
    refuse_unconverged: bool = True
    refuse_outside_priors: bool = True


class StaticSettings(BaseModel):
    """What a static sensor (or a user who asks) holds and checks: hold, parameters held at nominal (shell
    wildcards, e.g. 'fibre_*.d_elevation_deg'; None: STATIC_HOLD for a static sensor, else none); hold_soft,
    also hold what the start's strict pairs determine worse than firm_sigma_m / firm_sigma_deg; check_halves,
    fit each azimuth half of the scene and hold what they disagree on (None: for a static sensor)."""

    model_config = _SECTION
    hold: tuple[str, ...] | None = None
    hold_soft: bool | None = None
    firm_sigma_m: float = Field(0.01, gt=0)
    firm_sigma_deg: float = Field(0.05, gt=0)
    check_halves: bool | None = None

    @field_validator("hold")
    @classmethod
    def _hold_names_parameters(cls, hold: tuple[str, ...] | None) -> tuple[str, ...] | None:
        if hold is not None:
            held_names(hold, MAX_FIBRES, None)
        return hold


# the former flat settings -> their section (and name there), for a clear refusal of an old settings file
MOVED = {"neighbours": "association.neighbours", "fixed_association": "association.fixed",
         "min_planarity": "association.coarse.min_planarity",
         "max_normal_angle_deg": "association.coarse.max_normal_angle_deg",
         "max_plane_distance_m": "association.coarse.max_plane_distance_m",
         "gate_start_m": "association.coarse.gate_start_m", "gate_max_m": "association.coarse.gate_max_m",
         "gate_growth": "association.coarse.gate_growth", "coarse_max_points": "association.coarse.max_points",
         "coarse_pairs_per_fibre_pair": "association.coarse.pairs_per_fibre_pair",
         "fine_min_planarity": "association.fine.min_planarity",
         "fine_max_normal_angle_deg": "association.fine.max_normal_angle_deg",
         "fine_max_plane_distance_m": "association.fine.max_plane_distance_m",
         "fine_gate_m": "association.fine.gate_start_m and gate_max_m",
         "max_pairs_per_fibre_pair": "association.fine.pairs_per_fibre_pair",
         "feature_radius_m": "features.radius_m", "feature_neighbours": "features.neighbours",
         "feature_voxel_m": "features.voxel_m", "refresh_every": "features.refresh_every",
         "refresh_above_m": "features.refresh_above_m", "sigma0_m": "weighting.sigma0_m",
         "range_noise_m": "weighting.range_noise_m", "pair_noise": "weighting.pair_noise",
         "robust": "weighting.robust", "robust_k": "weighting.robust_k",
         "intrinsic_sigma_range_m": "priors.intrinsic_range_m", "intrinsic_sigma_angle_deg": "priors.intrinsic_angle_deg",
         "extrinsic_sigma_lever_arm_m": "priors.extrinsic_lever_arm_m",
         "extrinsic_sigma_boresight_deg": "priors.extrinsic_boresight_deg",
         "control_interval_s": "trajectory.control_interval_s", "block_controls": "trajectory.block_controls",
         "pose_corrections": "trajectory.pose_corrections", "lambda_rigid": "trajectory.lambda_rigid",
         "deformation": "trajectory.deformation", "max_outer_iterations": "stopping.max_outer_iterations",
         "tolerance_m": "stopping.tolerance_m", "fine_below_m": "stopping.fine_below_m",
         "plateau_iterations": "stopping.plateau_iterations", "plateau_improvement": "stopping.plateau_improvement",
         "step_sigma_m": "stopping.step_sigma_m", "step_sigma_deg": "stopping.step_sigma_deg",
         "lm_iterations": "stopping.lm_iterations", "refuse_unconverged": "stopping.refuse_unconverged",
         "hold": "static.hold", "hold_soft": "static.hold_soft", "firm_sigma_m": "static.firm_sigma_m",
         "firm_sigma_deg": "static.firm_sigma_deg", "check_halves": "static.check_halves"}


class CalibrationConfig(BaseModel):
    """Settings of graphcal.calibrate (module docstring): what to estimate (mode: auto, what a mapping drive
    needs, intrinsics and extrinsic, plus trajectory corrections when the drive comes back to where it was;
    a static sensor's intrinsics, held by its checks), how many of the recording's returns to use
    (max_points, a seeded random subset; None: all: the pairs per fibre pair are capped, so more returns
    mostly sharpen the normals), how dense along the drive they must stay (points_per_s, returns a second:
    when max_points spread over the whole drive would be thinner, they are drawn from spans of the drive at
    that density, graphcal.recording.subset; None: over the whole drive however thin; not with trajectory
    corrections, which need the whole drive), the seed of every random draw, and the sections."""

    model_config = ConfigDict(frozen=True, extra="forbid")
    mode: Mode = "auto"
    max_points: int | None = Field(4_000_000, ge=1000)
    points_per_s: float | None = Field(None, gt=0)
    seed: int = 0
    association: AssociationSettings = AssociationSettings()
    features: FeatureSettings = FeatureSettings()
    weighting: WeightingSettings = WeightingSettings()
    priors: PriorSettings = PriorSettings()
    accuracy: AccuracySettings = AccuracySettings()
    trajectory: TrajectorySettings = TrajectorySettings()
    stopping: StoppingSettings = StoppingSettings()
    static: StaticSettings = StaticSettings()

    @model_validator(mode="before")
    @classmethod
    def _no_flat_fields(cls, data):
        if isinstance(data, dict):
            moved = [f"{name} -> {MOVED[name]}" for name in data if name in MOVED]
            if moved:
                raise ValueError(f"settings moved into sections: {'; '.join(moved)}")
        return data

    def with_settings(self, **sections: dict) -> CalibrationConfig:
        """A copy with some fields of some sections changed and validated, e.g.
        with_settings(stopping={"tolerance_m": 1e-4}, association={"coarse": {"max_points": 100_000}})."""
        return self.model_copy(update={name: type(getattr(self, name)).model_validate(
            {**getattr(self, name).model_dump(), **fields}) for name, fields in sections.items()})

    def for_sensor(self, static: bool, range_noise_m: float = np.nan, revisits: bool = False,
                   one_viewpoint: bool | None = None) -> CalibrationConfig:
        """The settings left to the recording (None, mode auto) resolved for a static or a moving sensor whose
        range noise is range_noise_m (as measured when it was not set; NaN: unknown, left as set) and whose
        drive comes back to where it was or not (revisits). one_viewpoint (None: as static): the sensor stays in
        place, static or turning on the spot (returns.ReturnData.one_viewpoint); with no parallax its intrinsics
        take a static sensor's settings (held, checked, voxel features) while the mode and the fixed pairs follow
        static: a sensor turning on the spot estimates its extrinsic too, on pairs made again as it moves (pairs
        made once at a boresight 0.3 deg off left its roll 0.19 deg off, made again 0.02 deg). The coarse phase's
        plane-distance gate left None: COARSE_PLANE_DISTANCE_M unless the mode estimates the trajectory."""
        one_viewpoint = static if one_viewpoint is None else one_viewpoint
        mode = self.mode
        if mode == "auto":
            mode = "intrinsic" if static else ("joint_trajectory" if revisits else "joint")
        noise_m = self.weighting.range_noise_m if np.isnan(range_noise_m) else float(range_noise_m)
        noisy_head = noisy(np.nan if noise_m is None else noise_m)
        voxel_m = self.features.voxel_m
        if voxel_m is None:
            voxel_m = FEATURE_VOXEL_M if one_viewpoint or noisy_head else 0.0
        fixed = static if self.association.fixed is None else self.association.fixed
        lm = (5 if fixed else 2) if self.stopping.lm_iterations is None else self.stopping.lm_iterations
        plane_m = self.association.coarse.max_plane_distance_m
        if plane_m is None:
            plane_m = np.inf if estimated_by(mode)[2] else COARSE_PLANE_DISTANCE_M
        return self.model_copy(update={"mode": mode}).with_settings(
            association={"fixed": fixed, "coarse": {**self.association.coarse.model_dump(),
                                                    "max_plane_distance_m": plane_m}},
            features={"voxel_m": voxel_m},
            weighting={"range_noise_m": noise_m,
                       "pair_noise": self.weighting.pair_noise or ("incidence" if noisy_head else "uniform")},
            stopping={"lm_iterations": lm},
            static={"hold": (STATIC_HOLD if one_viewpoint else ()) if self.static.hold is None else self.static.hold,
                    "hold_soft": one_viewpoint if self.static.hold_soft is None else self.static.hold_soft,
                    "check_halves": one_viewpoint if self.static.check_halves is None else self.static.check_halves})

    def gates(self, phase: Phase) -> PhaseGates:
        """The association gates of a phase."""
        return self.association.coarse if phase == "coarse" else self.association.fine

    def in_phase(self, phase: Phase) -> CalibrationConfig:
        """The settings a phase solves with: the coarse phase whitens every pair by sigma0 (far from the
        solution the residuals are the calibration's errors, not the range noise's)."""
        return self.with_settings(weighting={"pair_noise": "uniform"}) if phase == "coarse" else self


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
