"""One calibration problem: the returns, the settings, the nominal model, its priors and which groups are
estimated; it associates, builds and solves the factor graph, runs the outer loop, finds the weak
directions and gives the final fit with its sigmas.

The outer loop (Algorithm 1 of the thesis, ICP-like): associate -> one GTSAM graph -> Levenberg-Marquardt
-> update. Energy of eq. 4.4/5.2: J = sum w d^2 / sum w, reported in cm^2, with d the point-to-plane
distance; the graph's cost is (W / sigma0^2) (J + lambda_rigid E_def) + priors, eq. 5.4 with J normalised
by the weight sum W, so each term of E_def (a control's correction, eq. 5.3, or the difference of two successive
ones, Monnier's) has sigma = sigma0 / sqrt(lambda_rigid W): the balance of data and rigidity does not depend on
how many pairs are drawn.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace

import gtsam
import numpy as np

from graphcal.calibration.association import Correspondences, Features, Sight
from factors.point_to_plane import Block, make_factor
from graphcal.calibration.blocks import make_blocks
from graphcal.calibration.config import (ESTIMATES, STAGES, CalibrationConfig, Phase, PhaseGates, estimated_by,
                                         held_names)
from graphcal.calibration.keys import E, I, X
from graphcal.calibration.observability import (
    POSE_TO_FILE_UNITS,
    Marginals,
    Uncertainty,
    assembled_dense,
    information_of,
    intrinsic_sigmas,
    pose_sigmas,
    reported,
    schur_complement,
    tangent_to_axes,
    tangent_widths,
)
from graphcal.calibration.pairing import Association, FeatureCache
from graphcal.calibration.levenberg_marquardt import levenberg_marquardt
from graphcal.calibration.priors import HELD_SIGMA, Priors, control_prior_sigma
from graphcal.calibration.returns import (Estimate, ReturnData, knot_shares, knots_every, mean_estimate, pose_of,
                                         prepare, resampled, revisits, sight_at, world_at)
from graphcal.calibration import cluster_robust
from graphcal.calibration.shared_returns import Linearised, shared_returns_covariance
from graphcal.calibration.tiles import Tiling
from graphcal.calibration.weak_directions import Layout, WeakDirections, lock_factor, tangent_about_nominal
from graphcal.common.cluster import IN_PROCESS, TaskMap
from graphcal.common.errors import ConfigError
from graphcal.common.progress import progress
from graphcal.recording.directory import Recording
from graphcal.recording.intrinsics import offsets_to_file_units

PHASES: tuple[Phase, ...] = ("coarse", "fine")
MIN_RETURNS = 10_000  # fewer cannot give pairs of neighbouring fibres on enough surfaces
# Monnier's differences are quadratic up to this many sigmas and linear beyond (Huber's 95 %-efficiency constant):
# an INS's error drifts smoothly between a GNSS update's steps, and a step pays in proportion to its size
JUMP_HUBER = 1.345


def enough_returns(recording: Recording) -> None:
    """ConfigError naming the recording when it holds fewer than MIN_RETURNS returns."""
    if len(recording.points) < MIN_RETURNS:
        raise ConfigError(f"{recording.path or recording.name}: {len(recording.points):,} returns; a calibration "
                          f"needs at least {MIN_RETURNS:,} (about 1/70 s of a 32-laser head) to pair returns of "
                          "neighbouring fibres on common surfaces")


@dataclass
class History:
    """Per outer iteration: J [cm^2] before/after the solve, weight sum, pairs, gate [m], step, and on the
    last of a stage's phase why it stopped (stop: converged, coarse done, or cap: n_max reached)."""

    rows: list = field(default_factory=list)

    def add(self, **row) -> None:
        self.rows.append(row)


@dataclass(frozen=True)
class FinalFit:
    """The strict pairs at the final estimate, their residuals [m], the sigmas of the model's marginals
    (uncertainty: gtsam.Marginals, or the sandwiches' factorised bread when those are made) and, for pairs whitened
    by the range noise, those counting each return's noise once over the pairs that share it (shared_returns;
    None otherwise), those of the pairs' own residuals clustered by time (cluster_robust, cluster_robust.py; None
    when the drive is too short), and the J [cm^2] the pairs' noise model predicts when they are whitened by the
    measured noise (None otherwise)."""

    pairs: Correspondences
    residual_m: np.ndarray
    uncertainty: Uncertainty
    shared_returns: Uncertainty | None
    cluster_robust: Uncertainty | None
    expected_energy_cm2: float | None

    def sigmas(self, held_shares: dict[str, float] | None = None) -> Uncertainty:
        """The 1-sigmas the calibration reports (observability.reported), bounded by the shares held at nominal."""
        return reported(self.uncertainty, self.shared_returns, self.cluster_robust, held_shares)


@dataclass(frozen=True)
class Problem:
    """A calibration problem in one phase (coarse: a subsample of the returns and the loose gates; fine: all
    returns and the strict gates). full: every return used; settings: the configuration resolved for the
    recording (CalibrationConfig.for_sensor); estimated: (intrinsics, extrinsic, trajectory); nominal:
    the nominal T_body_lidar; held: parameters held at nominal by the settings or the static checks;
    fixed_pairs: pairs made once and kept (a static sensor); lock: the factor holding the weak directions;
    effects: candidate effects modelled in every block (graphcal.diagnosis's EffectModel; None: none);
    tiling: features and pairs tile by tile of space (graphcal.calibration.tiles; None: the whole cloud); knots:
    the controls of full this problem's trajectory keys stand for, the others interpolated between them (the
    coarse phase's fit on a long drive: on_coarse_controls; None: every control)."""

    full: ReturnData
    settings: CalibrationConfig
    estimated: tuple[bool, bool, bool]
    nominal: gtsam.Pose3
    priors: Priors
    held: tuple[str, ...] = ()
    phase: Phase = "fine"
    data: ReturnData | None = None
    fixed_pairs: Correspondences | None = None
    lock: gtsam.CustomFactor | None = None
    effects: object | None = None
    cache: FeatureCache | None = None
    tiling: Tiling | None = None
    knots: np.ndarray | None = None

    def __post_init__(self):
        if self.data is None:
            object.__setattr__(self, "data", self.full)
        if self.cache is None:
            object.__setattr__(self, "cache", FeatureCache(self.settings.features, self.tiling))

    # --- what it is ------------------------------------------------------------------------------
    @classmethod
    def of(cls, recording: Recording, config: CalibrationConfig, task_map: TaskMap = IN_PROCESS) -> Problem:
        """The returns of the recording (a seeded subset of config.max_points) and the settings resolved for
        it; the parameters config.static.hold names held at nominal; the tiles' work (association.tile_m) run
        by task_map."""
        enough_returns(recording)
        data = prepare(recording, config.trajectory.control_interval_s, config.max_points,
                       np.random.default_rng(config.seed), range_noise_m=config.weighting.range_noise_m,
                       points_per_s=config.points_per_s)
        config = config.for_sensor(data.static, data.range_noise_m, revisits(recording.world.poses), data.one_viewpoint)
        try:  # the settings allow any head's fibres: this recording's head may have fewer, or fix the one named
            reference = data.sensor.reference_fibre
            held = held_names(config.static.hold, data.sensor.n_fibres, config.priors.fixed_fibre(reference))
            held += [name for name in config.priors.gauges(reference) if name not in held]
        except ConfigError as error:
            raise ConfigError(f"{recording.path or recording.name}: hold: {error} (sensor {data.sensor.model}, "
                              f"{data.sensor.n_fibres} fibres, reference fibre {data.sensor.reference_fibre})") from None
        estimated = estimated_by(config.mode)
        if estimated[2] and data.spans_s is not None:
            raise ConfigError(f"{recording.path or recording.name}: mode {config.mode} corrects the trajectory over "
                              f"the whole drive, but points_per_s {config.points_per_s:g} draws the {config.max_points} "
                              f"returns from {len(data.spans_s)} spans of it: raise max_points, unset points_per_s, "
                              "or choose a mode without trajectory corrections (joint)")
        priors = Priors.of(config, data.sensor.n_fibres, len(data.control_times_s)).holding(held)
        return cls(data, config, estimated, pose_of(recording.extrinsic), priors, tuple(held),
                   tiling=Tiling.of(config.association, config.features, task_map))

    @property
    def config(self) -> CalibrationConfig:
        """The settings this phase solves with."""
        return self.settings.in_phase(self.phase)

    @property
    def gates(self) -> PhaseGates:
        return self.settings.gates(self.phase)

    @property
    def stages(self) -> tuple[str, ...]:
        return STAGES.get(self.settings.mode, (self.settings.mode,))

    def in_phase(self, phase: Phase) -> Problem:
        """This problem in a phase: the coarse one on a seeded subset of its returns (with its own features);
        on fixed pairs (made on every return) there is only the fine phase."""
        if phase == "fine" or self.fixed_pairs is not None:
            return replace(self, phase="fine", data=self.full, cache=None if self.phase == "coarse" else self.cache,
                           knots=None)
        most = self.settings.association.coarse.max_points
        sample = self.full if most is None else self.full.sample(most, np.random.default_rng(self.settings.seed))
        return replace(self, phase="coarse", data=sample, cache=None if sample is not self.full else self.cache,
                       knots=None)

    def on_coarse_controls(self) -> Problem:
        """This problem with trajectory keys at every k-th control only (trajectory.coarse_max_controls), when it
        corrects the trajectory of a drive with more controls than that; else itself."""
        knots = knots_every(len(self.full.control_times_s), self.settings.trajectory.coarse_max_controls,
                            self.full.about_breaks)
        if knots is None or not self.estimated[2]:
            return self
        return replace(self, data=self.data.on_knots(knots), knots=knots)

    def own(self, estimate: Estimate) -> Estimate:
        """The estimate (corrections at every control) with corrections at this problem's keys only."""
        if self.knots is None or len(estimate.corrections) == len(self.knots):
            return estimate
        return replace(estimate, corrections=tuple(estimate.corrections[k] for k in self.knots))

    def at_every_control(self, estimate: Estimate) -> Estimate:
        """The estimate of this problem's keys with corrections at every control (interpolated between knots)."""
        if self.knots is None or len(estimate.corrections) != len(self.knots):
            return estimate
        return replace(estimate, corrections=resampled(estimate.corrections, self.data.control_times_s,
                                                        self.full.control_times_s))

    def in_stage(self, stage: str) -> Problem:
        """This problem estimating what one stage of the mode estimates."""
        return replace(self, estimated=ESTIMATES[stage])

    def holding(self, names: list[str]) -> Problem:
        """This problem with the named parameters held at nominal."""
        return replace(self, priors=self.priors.holding(names), held=self.held + tuple(n for n in names if n not in self.held))

    def locking(self, weak: WeakDirections) -> Problem:
        """This problem with the weak directions (of the groups it estimates) held at nominal."""
        held = weak.restricted(*self.estimated[:2])
        return replace(self, lock=lock_factor(held, [I(f) for f in held.layout.fibres],
                                              E(0) if held.layout.extrinsic else None, self.nominal))

    # --- association ---------------------------------------------------------------------------------
    def points(self, estimate: Estimate, rows: np.ndarray | None = None) -> np.ndarray:
        """World points [m] (minus the origin) of the phase's returns at the estimate, one row per return; with
        rows, only those are placed and the others are NaN (fixed pairs need only their own returns)."""
        pose = self.config.trajectory.pose_corrections
        placed = (self.effects.world(self.data, estimate, pose, rows) if self.effects is not None
                  else world_at(self.data, estimate, pose, rows))
        if rows is None:
            return placed
        points = np.full((len(self.data.time_s), 3), np.nan)
        points[rows] = placed
        return points

    def sight(self, estimate: Estimate) -> Sight | None:
        """What the association chooses m by: stand-ins (sight_at), in both phases (the coarse phase's subsample with
        the whole drive's, ReturnData.sample). With plain nearest returns the coarse phase's pairs carry the range
        noise (associate) and slide along the weak directions: a tilted head's minute over an open road took 29 outer
        iterations (elevations 0.78 deg RMS off at the switch), 10 with stand-ins."""
        return sight_at(self.data, estimate)

    def association(self) -> Association:
        """The phase's association; in the fine phase, near the solution, it rejects the pairs seen on moving
        objects (graphcal.calibration.moving): far from it a fibre pair's residuals are the calibration's
        errors, as varied as the surfaces it sees."""
        settings = self.settings
        return Association.of(self.data, self.gates, settings.association.neighbours, settings.seed, self.tiling,
                              settings.association if self.phase == "fine" else None)

    def associate(self, estimate: Estimate, points_m: np.ndarray | None = None,
                  features: Features | None = None) -> Correspondences:
        """The pairs at the estimate with the phase's gates at their starting gate (fixed_pairs when set);
        features from the cache when the cloud has not moved since they were computed."""
        if self.fixed_pairs is not None:
            return self.fixed_pairs
        points_m = self.points(estimate) if points_m is None else points_m
        features = self.cache.at(points_m, estimate)[0] if features is None else features
        return self.cache.pairs(self.association(), points_m, self.data.fibre, features, self.gates.gate_start_m,
                                lambda: self.sight(estimate))

    # --- the factor graph ----------------------------------------------------------------------------
    def blocks(self, estimate: Estimate, pairs: Correspondences) -> list:
        return list(self.each_block(estimate, pairs))

    def each_block(self, estimate: Estimate, pairs: Correspondences) -> Iterator[tuple[np.ndarray, Block]]:
        """The block factors' data one at a time (rows in pairs, Block): a pass over the pairs that holds one
        block's per-row data, not every block's."""
        effects = None if self.effects is None else self.effects.with_values(estimate.effects)
        return make_blocks(self.data, estimate, pairs, self.config, self.estimated, effects)

    def graph(self, estimate: Estimate, pairs: Correspondences, damped: bool = True,
              blocks: list | None = None) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
        """One graph: the block factors of the pairs, the priors, the lock, the candidate effects. damped adds a
        prior at the current estimate on every key (stopping.step_sigma_*): one outer iteration cannot run far
        along directions the current pairs barely see; it leaves the fixed point unchanged and is left out when
        sigmas are computed."""
        weighting = self.config.weighting
        robust = None
        if weighting.robust != "none":
            scheme = gtsam.noiseModel.mEstimator.Base.ReweightScheme.Scalar
            create = {"huber": gtsam.noiseModel.mEstimator.Huber, "cauchy": gtsam.noiseModel.mEstimator.Cauchy}
            robust = create[weighting.robust].Create(weighting.robust_k, scheme)
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        for _, block in self.blocks(estimate, pairs) if blocks is None else blocks:
            graph.add(make_factor(block, compressed=robust is None, robust=robust))
        if self.effects is not None:
            self.effects.with_values(estimate.effects).add_to(graph, values)
        if self.lock is not None:
            graph.add(self.lock)
        self._add_priors(graph, values, estimate, damped, float(pairs.weight.sum()))
        return graph, values

    def _add_priors(self, graph, values, estimate: Estimate, damped: bool, weight_sum: float) -> None:
        """Values and priors of the estimated keys (and the damping priors, see graph)."""
        est_int, est_ext, est_traj = self.estimated
        stopping = self.config.stopping
        step_m, step_rad = stopping.step_sigma_m, np.radians(stopping.step_sigma_deg)
        if est_int:
            for fibre in range(self.data.sensor.n_fibres):
                if fibre != self.fixed_fibre:
                    values.insert(I(fibre), estimate.offsets[fibre])
                    graph.add(gtsam.PriorFactorVector(I(fibre), np.zeros(4),
                                                      gtsam.noiseModel.Diagonal.Sigmas(self.priors.intrinsic[fibre])))
                    if damped:
                        graph.add(gtsam.PriorFactorVector(I(fibre), estimate.offsets[fibre], gtsam.noiseModel.Diagonal.Sigmas(
                            np.array([step_m, step_rad, step_rad, step_m]))))
        if est_ext:
            values.insert(E(0), estimate.extrinsic)
            graph.add(gtsam.PriorFactorPose3(E(0), self.nominal,
                                             self.priors.extrinsic_noise(self.nominal.rotation().matrix())))
            if damped:
                graph.add(gtsam.PriorFactorPose3(E(0), estimate.extrinsic, gtsam.noiseModel.Diagonal.Sigmas(
                    np.r_[np.full(3, step_rad), np.full(3, step_m)])))
        if est_traj:
            self._add_trajectory(graph, values, estimate, damped, control_prior_sigma(self.config, weight_sum))

    def _add_trajectory(self, graph, values, estimate: Estimate, damped: bool, sigma: float) -> None:
        """Control corrections and E_def: the seed's eq. 5.3 (a prior of sigma on each control) or Monnier's
        successive differences (the seed's quotation after eq. 5.3) under a Huber loss of JUMP_HUBER sigmas, with a
        prior of sigma sqrt(N) on each of the N controls, which holds the drive's mean correction (the gauge) with
        sigma, on every control's INS value, and pulls no stretch back. A difference over a time of g control
        intervals has g times a difference's variance (on knots, on_coarse_controls: the controls' successive
        differences between two knots, corrections linear between them; about a step of the INS: the shorter
        intervals); across a step of the INS the difference is minus the recorded step (ReturnData.control_steps_m:
        the vehicle does not jump, the INS's error does), with the step's own sigma added, as loose as a difference
        over one control interval at least (the INS's drift over the step's sample is not the random walk E_def
        models: a velocity error of 0.3 m/s moves 3 mm in 10 ms), and with no Huber loss: the step is measured,
        not a jump to let through, and in its linear tail a stretch between two steps could slide along a street the
        coarse pairs see weakly (an hour at 4 M returns: 1.3 m at the coarse phase's end, 55 cm after the fine
        one). On knots each prior is
        that of the controls the knot stands for (knot_shares)."""
        trajectory, stopping = self.config.trajectory, self.config.stopping
        pose = trajectory.pose_corrections
        shares = np.ones(len(estimate.corrections)) if self.knots is None else knot_shares(self.full.control_times_s,
                                                                                            self.knots)
        interval_s = trajectory.control_interval_s
        gaps = (np.r_[1.0, np.diff(self.data.control_times_s) / interval_s] if np.isfinite(interval_s)
                else np.ones(len(estimate.corrections)))  # in control intervals
        steps_m = np.zeros((len(gaps), 3)) if self.data.control_steps_m is None else self.data.control_steps_m
        breaks = np.any(steps_m != 0, axis=1)
        monnier = trajectory.deformation == "monnier"
        anchor = self._anchor_sigma(sigma)

        def isotropic(sigma_m: float):  # rotations: rad x 1 m
            return gtsam.noiseModel.Isotropic.Sigma(6 if pose else 3, sigma_m)

        anchors = [isotropic(anchor / np.sqrt(share)) for share in shares]
        huber = gtsam.noiseModel.mEstimator.Huber.Create  # a difference over n controls: sigma, threshold x sqrt(n)

        def difference(gap: float, stepped: bool):  # over gap control intervals; across a step as over one at least
            gap = max(gap, 1.0) if stepped else gap
            translation_m = np.full(3, np.sqrt(sigma ** 2 * gap + (self.data.step_sigma_m ** 2 if stepped else 0.0)))
            gaussian = gtsam.noiseModel.Diagonal.Sigmas(np.r_[np.full(3, sigma * np.sqrt(gap)), translation_m] if pose
                                                        else translation_m)
            return gaussian if stepped else gtsam.noiseModel.Robust.Create(huber(JUMP_HUBER * np.sqrt(gap)), gaussian)

        differences = [difference(gap, stepped) for gap, stepped in zip(gaps, breaks)] if monnier else []
        step = gtsam.noiseModel.Diagonal.Sigmas(np.r_[np.full(3, np.radians(stopping.step_sigma_deg)),
                                                      np.full(3, stopping.step_sigma_m)] if pose
                                                else np.full(3, stopping.step_sigma_m))
        prior = (lambda c, n: gtsam.PriorFactorPose3(X(c), gtsam.Pose3(), n)) if pose else \
            (lambda c, n: gtsam.PriorFactorPoint3(X(c), np.zeros(3), n))
        held = self.priors.control_held if self.knots is None else self.priors.control_held[self.knots]
        for c, correction in enumerate(estimate.corrections):
            values.insert(X(c), correction if pose else correction.translation())
            if damped:
                graph.add(gtsam.PriorFactorPose3(X(c), correction, step) if pose
                          else gtsam.PriorFactorPoint3(X(c), correction.translation(), step))
            graph.add(prior(c, anchors[c]))
            if monnier and c > 0:
                graph.add(gtsam.BetweenFactorPose3(X(c - 1), X(c), gtsam.Pose3(gtsam.Rot3(), -steps_m[c]),
                                                   differences[c]) if pose
                          else gtsam.BetweenFactorPoint3(X(c - 1), X(c), -steps_m[c], differences[c]))
            if held[c].any():
                graph.add(prior(c, gtsam.noiseModel.Diagonal.Sigmas(np.where(held[c], HELD_SIGMA, 1e6))))

    @property
    def fixed_fibre(self) -> int | None:
        """The fibre with no key in the graph (PriorSettings.fixed_fibre: the reference, unless priors.reference_fibre
        estimates its range and elevation)."""
        return self.settings.priors.fixed_fibre(self.full.sensor.reference_fibre)

    def _anchor_sigma(self, sigma: float) -> float:
        """E_def's prior [m, or rad x 1 m] on each control correction: sigma (eq. 5.3), or sigma sqrt(N) on each of
        the N controls under Monnier's differences (which hold the drive's mean correction with sigma)."""
        return sigma * np.sqrt(len(self.full.control_times_s)) if self.config.trajectory.deformation == "monnier" \
            else sigma

    def common_translation_variance(self, sigma: float) -> np.ndarray:
        """(3,) [m^2] the variance E_def leaves to the drive's common translation along each world axis, present in
        every control's marginal: the data never see it (every return moves rigidly with it) and Monnier's
        differences do not either, so only the anchors (and a held component's prior) hold it. With uniform anchors
        it is an eigen-direction of the posterior covariance, of the model's marginals and of the sandwiches alike
        (their meat carries the priors' information): subtracting it from a control's variance leaves the variance
        about the drive's mean."""
        controls = len(self.full.control_times_s)
        held = self.priors.control_held[:, -3:].sum(axis=0)
        return 1.0 / (controls / self._anchor_sigma(sigma) ** 2 + held / HELD_SIGMA ** 2)

    def step(self, estimate: Estimate, pairs: Correspondences) -> Estimate:
        """One solve on the pairs (stopping.lm_iterations of Levenberg-Marquardt), read back."""
        graph, values = self.graph(estimate, pairs)
        solved = levenberg_marquardt(graph, values, self.config.stopping.lm_iterations)
        return self.read_back(solved, estimate)

    def read_back(self, values: gtsam.Values, estimate: Estimate) -> Estimate:
        """The estimate held in solved values."""
        est_int, est_ext, est_traj = self.estimated
        offsets = estimate.offsets.copy()
        if est_int:
            for fibre in range(self.data.sensor.n_fibres):
                if fibre != self.fixed_fibre:
                    offsets[fibre] = values.atVector(I(fibre))
        extrinsic = values.atPose3(E(0)) if est_ext else estimate.extrinsic
        corrections = estimate.corrections
        if est_traj:
            pose = self.config.trajectory.pose_corrections
            corrections = tuple(values.atPose3(X(c)) if pose else gtsam.Pose3(gtsam.Rot3(), values.atPoint3(X(c)))
                                for c in range(len(corrections)))
        effects = estimate.effects if self.effects is None else self.effects.read(values)
        return Estimate(offsets, extrinsic, corrections, effects)

    # --- the outer loop ------------------------------------------------------------------------------
    def fit(self, estimate: Estimate, history: History, label: str, phases: tuple[Phase, ...] = PHASES,
            max_iterations: int | None = None, quiet: bool = True,
            after_each: Callable[[Estimate, Estimate | None, tuple], None] | None = None, ran: int = 0,
            features_at: Estimate | None = None, plateau_from: tuple[float, ...] = (),
            window: tuple[Estimate, ...] = (), stall: bool = False) -> Estimate:
        """Outer iterations of one stage from this problem: the coarse phase (its subsample, the gate opening
        by gate_growth) until its step (step_size) falls below stopping.fine_below_m, then the fine phase until it
        falls below stopping.tolerance_m, J plateaus, or n_max (max_iterations, else stopping.max_outer_iterations,
        both phases together). phases: the phases to run (("coarse",): stop at the switch; ("fine",): start
        there). On fixed pairs, the fine phase only. Features are refreshed every features.refresh_every outer
        iterations, when the cloud has moved. A fine phase that stops on J's plateau returns the mean (mean_estimate)
        of its last stopping.plateau_iterations outer iterations' estimates (window): once J is flat, each outer
        iteration's pairs and features made again move the weakest parameters by about their sigmas, and the mean
        damps that (Polyak-Ruppert averaging); one whose step fell below stopping.tolerance_m, or on fixed pairs,
        returns its last. after_each(estimate, features_at, window): called after each outer
        iteration, once its history row is complete, with the estimate its features were computed at (None: not
        known) and the fine iterations' window. ran: the outer iterations of this fit an interrupted calibration had
        run (the last rows of history, estimate their end, features_at and window what after_each last gave): it
        goes on from them as it would have. plateau_from: the J curve [cm^2] of a fine phase this one goes on from
        (the same stage's, run again with more held): the plateau test continues it, once a step is below
        stopping.fine_below_m (the fine phase run again otherwise restarts the test and makes plateau_iterations + 1
        outer iterations whatever it moves). J's plateau counts only once the window no longer drifts (drifting):
        along a weak direction J is flat while the outer iterations still converge, each a fraction of the way
        (a tilted head over an open road: elevations 0.14 -> 0.010 deg RMS over eight fine iterations, with J flat
        from the third). stall: the coarse phase also stops (stop "stalled") once its J has made no new low for
        stopping.plateau_iterations outer iterations at its full gate (coarse_stalled), its step still above
        stopping.fine_below_m: it wanders instead of settling, and the caller has a remedy (CalibrationPipeline's
        coarse phase run again with the intrinsics held)."""
        stopping, refresh_every = self.settings.stopping, self.settings.features.refresh_every
        n_max = stopping.max_outer_iterations if max_iterations is None else max_iterations
        first_row = len(history.rows) - ran
        done = history.rows[first_row:]
        fine = (self.fixed_pairs is not None or phases[0] == "fine"
                or any(row["phase"] == "fine" or row["max_step"] < stopping.fine_below_m for row in done))
        if (fine and "fine" not in phases) or n_max <= ran:
            return estimate
        problem = self.in_phase("fine") if fine else self.in_phase("coarse").on_coarse_controls()
        estimate = problem.own(estimate)
        features_at = None if features_at is None else problem.own(features_at)
        gate, association = problem.gates.gate_start_m, problem.association()
        if done and not fine:
            gate = min(done[-1]["gate_m"] * problem.gates.gate_growth, problem.gates.gate_max_m)
        features, refreshed, points, since_refresh, sigma = None, False, None, refresh_every, None
        fine_energies = list(plateau_from) + [row["energy_cm2"] for row in done if row["phase"] == "fine"]
        rows = None if problem.fixed_pairs is None else problem.fixed_pairs.rows()  # fixed pairs: only their returns
        in_phase = [row for row in done if row["phase"] == problem.phase]
        if in_phase and features_at is not None and problem.fixed_pairs is None:  # as they were when interrupted
            features = problem.cache.at(problem.points(features_at, rows), features_at)[0]
            last = max((i for i, row in enumerate(in_phase) if row["refreshed"]), default=None)
            since_refresh = refresh_every + len(in_phase) if last is None else len(in_phase) - last
        for _ in progress(range(ran, n_max), f"calibrating ({label}; outer iterations, at most {n_max})",
                          total=n_max - ran, quiet=quiet):
            points = problem.points(estimate, rows) if points is None else points
            if problem.fixed_pairs is None and (features is None or since_refresh >= refresh_every):
                features, refreshed = problem.cache.at(points, estimate)
                since_refresh = 0 if refreshed else since_refresh
            since_refresh += 1
            pairs = problem.fixed_pairs if problem.fixed_pairs is not None else problem.cache.pairs(
                association, points, problem.data.fibre, features, gate, lambda: problem.sight(estimate))
            before, weight_sum = energy_cm2(points[pairs.index_p], points[pairs.index_m], pairs)
            updated = problem.step(estimate, pairs)
            step = step_size(estimate, updated, problem.phase)
            points = problem.points(updated, rows)  # the next iteration's too
            after, _ = energy_cm2(points[pairs.index_p], points[pairs.index_m], pairs)
            history.add(mode=label, iteration=len(history.rows), phase=problem.phase, energy_cm2=before,
                        energy_after_cm2=after, weight_sum=weight_sum, pairs=len(pairs), gate_m=gate, max_step=step,
                        refreshed=refreshed, stop="")
            estimate, refreshed = updated, False
            if problem.phase == "fine":
                fine_energies.append(before)
                window = (*window, estimate)[-stopping.plateau_iterations:]
                settled = not plateau_from or step < stopping.fine_below_m
                flat = settled and on_plateau(fine_energies, stopping.plateau_iterations, stopping.plateau_improvement)
                averaged = flat and step >= stopping.tolerance_m and problem.fixed_pairs is None
                if averaged:
                    sigma = problem.calibration_sigmas(estimate, pairs) if sigma is None else sigma
                    flat = averaged = not problem.drifting(window, sigma)
                if step < stopping.tolerance_m or flat:
                    history.rows[-1]["stop"] = "converged"
                if averaged:
                    estimate = mean_estimate(window)
            elif step < stopping.fine_below_m:
                if "fine" not in phases:
                    history.rows[-1]["stop"] = "coarse done"
                else:
                    estimate, problem = problem.at_every_control(estimate), self.in_phase("fine")
                    gate, association = problem.gates.gate_start_m, problem.association()
                    since_refresh, features, points = refresh_every, None, None
            elif stall and coarse_stalled(history.rows[first_row:], problem.gates.gate_max_m,
                                          stopping.plateau_iterations, stopping.plateau_improvement):
                history.rows[-1]["stop"] = "stalled"
            else:
                gate = min(gate * problem.gates.gate_growth, problem.gates.gate_max_m)
            if after_each is not None:
                after_each(problem.at_every_control(estimate),
                           None if features is None else problem.at_every_control(problem.cache.estimate), window)
            if history.rows[-1]["stop"]:
                break
        else:
            if history.rows:
                history.rows[-1]["stop"] = "cap"
        return problem.at_every_control(estimate)

    def calibration_sigmas(self, estimate: Estimate, pairs: Correspondences) -> np.ndarray:
        """(P,) the 1-sigma of layout()'s parameters in their keys' tangent coordinates (m, rad) from the pairs'
        information at the estimate (information: the trajectory marginalised out) and the priors."""
        layout = self.layout()
        if not layout.size:
            return np.zeros(0)
        to_whitened = np.linalg.inv(layout.tangent_from_whitened())
        information = self.information(estimate, pairs, self.calibration_keys()) + to_whitened.T @ to_whitened
        return np.sqrt(np.diag(np.linalg.inv(information)))

    def drifting(self, window: tuple[Estimate, ...], sigma: np.ndarray) -> bool:
        """Whether the window's estimates still move together: for some kind of parameter (each intrinsic offset
        across the free fibres, the extrinsic's rotation, its lever arm) the median of |last - first| / sigma is
        above stopping.trend_sigmas. The association's jitter about a settled estimate moves it by a fraction of its
        sigma (0.2-0.5 over six iterations on a tilted open road), an outer loop still converging along a weak
        direction by several sigmas (5-30 there)."""
        layout, nominal = self.layout(), self.nominal
        first, last = (tangent_about_nominal(layout, e.offsets, e.extrinsic, nominal) for e in (window[0], window[-1]))
        moved = np.abs(last - first) / sigma
        n = 4 * len(layout.fibres)
        kinds = [moved[:n].reshape(-1, 4)[:, k] for k in range(4) if n] + ([moved[n:n + 3], moved[n + 3:]] if
                                                                           layout.extrinsic else [])
        return any(float(np.median(kind)) > self.settings.stopping.trend_sigmas for kind in kinds)

    # --- what the data see ---------------------------------------------------------------------------
    def layout(self) -> Layout:
        """The parameters a weak-direction analysis covers: the intrinsics of every fibre but the fixed one (when
        estimated) and the extrinsic (when estimated), with their prior sigmas."""
        data, estimated = self.full, self.estimated
        fibres = tuple(f for f in range(data.sensor.n_fibres) if f != self.fixed_fibre) if estimated[0] else ()
        sigma = np.r_[self.priors.intrinsic[list(fibres)].ravel(), self.priors.extrinsic if estimated[1] else np.zeros(0)]
        return Layout(fibres, estimated[1], sigma, self.nominal.rotation().matrix())

    def calibration_keys(self) -> list[int]:
        """The graph keys of layout()'s parameters: the free fibres' intrinsics, then the extrinsic if estimated."""
        layout = self.layout()
        return [I(f) for f in layout.fibres] + ([E(0)] if layout.extrinsic else [])

    def reported_axes(self, estimate: Estimate) -> dict[int, np.ndarray]:
        """{calibration key: the map of its tangent into the axes uncertainty() reports it in}: the identity for
        an intrinsic, the extrinsic's rotation for its pose (observability.tangent_to_axes)."""
        return {key: (tangent_to_axes(estimate.extrinsic.rotation().matrix()) if key == E(0) else np.eye(4))
                for key in self.calibration_keys()}

    def weak_directions(self, estimate: Estimate) -> WeakDirections:
        """The weak directions of the data's information at the estimate, on this phase's pairs there."""
        layout = self.layout()
        if not layout.size:
            return WeakDirections.none(layout)
        return WeakDirections.of(self.information(estimate, self.associate(estimate), self.calibration_keys()), layout)

    def information(self, estimate: Estimate, pairs: Correspondences, keys: list[int]) -> np.ndarray:
        """The Gauss-Newton information (in the keys' tangent coordinates) that the pairs alone carry on the
        given intrinsic and extrinsic keys, the trajectory corrections, when estimated, marginalised out with
        their own priors (E_def, held components): no prior on the calibration's keys is in it. The corrections
        are eliminated from the sparse linearised graph (GTSAM's partial multifrontal elimination, the keys kept
        last): the Schur complement without a dense matrix over every control; from a graph large and nearly dense
        (observability.assembled_dense: a long drive that comes back), by LAPACK on the assembled dense H."""
        graph, values = self._pairs_graph(estimate, pairs)
        if self.estimated[2]:
            self._add_trajectory(graph, gtsam.Values(), estimate, False,
                                 control_prior_sigma(self.config, float(pairs.weight.sum())))
        widths = tangent_widths(values)
        if assembled_dense(graph, widths):
            return schur_complement(information_of(graph, values, widths, dense=True), widths, keys)
        linear = graph.linearize(values)
        present = set(linear.keyVector())
        reached = [key for key in keys if key in present]
        if len(present) > len(reached):
            order = gtsam.Ordering.ColamdConstrainedLastGaussianFactorGraph(linear, reached)
            _, linear = linear.eliminatePartialMultifrontal(
                gtsam.Ordering([order.at(i) for i in range(order.size() - len(reached))]))
        starts = np.r_[0, np.cumsum([widths[key] for key in keys])]
        spans = {key: np.arange(a, b) for key, a, b in zip(keys, starts[:-1], starts[1:])}
        columns = np.concatenate([spans[key] for key in reached]) if reached else np.zeros(0, int)
        information = np.zeros((starts[-1], starts[-1]))
        if reached:
            information[np.ix_(columns, columns)] = linear.hessian(gtsam.Ordering(reached))[0]
        return information

    def _pairs_graph(self, estimate: Estimate,
                     pairs: Correspondences) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
        """The pairs' block factors alone (no prior), with the estimated keys' values at the estimate."""
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        for _, block in self.blocks(estimate, pairs):
            graph.add(make_factor(block))
        self._add_priors(gtsam.NonlinearFactorGraph(), values, estimate, False, float(pairs.weight.sum()))
        return graph, values

    # --- the result ----------------------------------------------------------------------------------
    def final(self, estimate: Estimate, pairs: Correspondences | None = None, shared_returns: bool = False) -> FinalFit:
        """The fit at the estimate on the given pairs (None: the strict association at the estimate): residuals,
        the marginals of the undamped graph without the lock (the weak directions' uncertainty is their
        priors'; the sandwiches' bread when shared_returns or the clustered sigmas make one), and with
        shared_returns the sigmas of shared_returns.py when the pairs are whitened by the range noise and no
        robust loss reweights them."""
        problem = replace(self.in_phase("fine"), lock=None)
        pairs = problem.associate(estimate) if pairs is None else pairs
        points = problem.points(estimate)
        apart_m = points[pairs.index_p] - points[pairs.index_m]
        residual = np.einsum("ni,ni->n", pairs.normal, apart_m)
        blocks = problem.blocks(estimate, pairs)
        graph, values = problem.graph(estimate, pairs, damped=False, blocks=blocks)
        control_sigma = control_prior_sigma(problem.config, float(pairs.weight.sum()))
        weighting = problem.config.weighting
        shared = expected = robust = None
        time_s = problem.data.time_s[pairs.index_p]
        with_shared = weighting.pair_noise == "incidence" and shared_returns and weighting.robust == "none"
        with_robust = bool(blocks) and cluster_robust.determined(time_s)
        linearised = (Linearised.of(graph, values, blocks, len(pairs), weighting.robust != "none")
                      if with_shared or with_robust else None)
        if with_shared:
            shared = problem.uncertainty(shared_returns_covariance(linearised, pairs, problem.data, estimate,
                                                                   weighting.sigma0_m), estimate, control_sigma)
        if weighting.pair_noise == "incidence" and blocks:  # pairs whitened by the measured noise: the J it predicts
            weight = np.concatenate([block.weight for _, block in blocks])
            sigma = np.concatenate([np.broadcast_to(block.sigma0_m, len(block.weight)) for _, block in blocks])
            expected = float((weight * sigma ** 2).sum() / weight.sum() * 1e4)
        if with_robust:
            classes = cluster_robust.surface_classes(pairs.normal, np.linalg.norm(apart_m, axis=1))
            robust = problem.uncertainty(cluster_robust.cluster_robust_covariance(
                linearised, time_s, classes, problem.reported_axes(estimate)), estimate, control_sigma)
        # the sandwiches' bread is this graph's information, factorised: the model's marginals too
        model = Marginals(graph, values) if linearised is None else linearised.bread
        return FinalFit(pairs, residual, problem.uncertainty(model, estimate, control_sigma), shared, robust, expected)

    def uncertainty(self, marginals, estimate: Estimate, control_sigma: float) -> Uncertainty:
        """Posterior and prior sigmas in file units (m, deg) for every estimated parameter."""
        est_int, est_ext, est_traj = self.estimated
        data, priors = self.data, self.priors
        n = data.sensor.n_fibres
        intrinsics = np.full((n, 4), np.nan)
        if est_int:
            for fibre in range(n):
                if fibre != self.fixed_fibre:
                    intrinsics[fibre] = intrinsic_sigmas(marginals, I(fibre))
        extrinsic = extrinsic_prior = None
        if est_ext:
            extrinsic = pose_sigmas(marginals.marginalCovariance(E(0)), estimate.extrinsic.rotation().matrix())
            extrinsic_prior = priors.extrinsic * POSE_TO_FILE_UNITS
        controls = controls_prior = None
        if est_traj:
            rows, prior_rows = [], []
            common = self.common_translation_variance(control_sigma)
            for c, correction in enumerate(estimate.corrections):
                cov = marginals.marginalCovariance(X(c)).copy()
                cov[-3:, -3:] -= np.diag(np.minimum(common, np.diag(cov)[-3:]))  # about the drive's mean
                if self.config.trajectory.pose_corrections:
                    rows.append(pose_sigmas(cov, correction.rotation().matrix()))
                else:
                    rows.append(np.r_[np.full(3, np.nan), np.sqrt(np.diag(cov))])
                held = np.r_[np.zeros(6 - priors.control_held.shape[1], bool), priors.control_held[c]]
                prior_rows.append(np.where(held, HELD_SIGMA, control_sigma) * POSE_TO_FILE_UNITS)
            controls, controls_prior = np.array(rows), np.array(prior_rows)
        return Uncertainty(intrinsics, offsets_to_file_units(priors.intrinsic), extrinsic, extrinsic_prior, controls,
                           controls_prior)


def energy_cm2(p_m: np.ndarray, m_m: np.ndarray, pairs: Correspondences) -> tuple[float, float]:
    """(J [cm^2], weight sum) of eq. 4.4 for the paired world points p, m (K,3) [m], with the
    correspondences' fixed normals and weights."""
    d = np.einsum("ni,ni->n", pairs.normal, p_m - m_m)
    weight_sum = float(pairs.weight.sum())
    return float((pairs.weight * d * d).sum() / weight_sum * 1e4), weight_sum


def step_size(a: Estimate, b: Estimate, phase: Phase = "fine") -> float:
    """The outer step from a to b: m for lengths, rad (x 1 m) for angles. Fine phase: max |dX| over every
    parameter. Coarse phase: the largest over the intrinsics and the extrinsic, and the median over the
    trajectory's controls (each its largest component): a long drive's coarse subset reaches some controls
    with a few pairs only, and they step centimetres every iteration while the calibration has settled
    (city_loop, 5 min, 250 k coarse returns: 60 iterations without switching, the largest control step
    3-13 cm, the intrinsics' below 2 mm); the fine phase's denser pairs settle them."""
    calibration = max(np.abs(a.offsets - b.offsets).max(), np.abs(a.extrinsic.localCoordinates(b.extrinsic)).max())
    controls = np.array([np.abs(x.localCoordinates(y)).max() for x, y in zip(a.corrections, b.corrections)])
    if not len(controls):
        return float(calibration)
    return float(max(calibration, np.median(controls) if phase == "coarse" else controls.max()))


def coarse_stalled(rows: list[dict], gate_max_m: float, iterations: int, improvement: float) -> bool:
    """True when the coarse phase's J (rows: a fit's history rows) at its full gate (gate_m at gate_max_m: a gate
    still opening lets J rise with the pairs it admits) has made no new low for `iterations` outer iterations
    (on_plateau). Measured: sim6_turn's level head with trajectory corrections, 1 M returns: its J reached 0.33 cm² at
    the seventh outer iteration and wandered between 0.33 and 1.5 cm² until the cap of 60, its step never below
    1 cm, while the upward fibres' elevations slid 2-3 deg."""
    energies = [row["energy_cm2"] for row in rows if row["phase"] == "coarse" and row["gate_m"] >= gate_max_m]
    return on_plateau(energies, iterations, improvement)


def on_plateau(energies: list[float], iterations: int, improvement: float) -> bool:
    """True when none of the last `iterations` energies fell below (1 - improvement) times the
    lowest one before them: J has stopped falling (it only jitters with the association)."""
    if len(energies) <= iterations:
        return False
    return min(energies[-iterations:]) > (1.0 - improvement) * min(energies[:-iterations])
