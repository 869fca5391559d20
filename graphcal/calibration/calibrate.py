"""graphcal.calibrate: the pipeline of one calibration, one line per step."""

from __future__ import annotations

import functools
import time
from contextlib import nullcontext
from dataclasses import replace
from pathlib import Path

from threadpoolctl import threadpool_limits

from graphcal.calibration.accuracy import imprecise
from graphcal.calibration.checkpoint import Checkpoint, PipelineState
from graphcal.calibration.checks import (
    check_converged,
    check_energy_explained,
    check_energy_fell,
    check_fibres_apart,
    check_rings_in_order,
    check_within_priors,
)
from graphcal.calibration.config import CalibrationConfig, Phase
from graphcal.calibration.observability import EXTRINSIC_NAMES, INTRINSIC_NAMES, TRAJECTORY_GAUGE
from graphcal.calibration.problem import PHASES, FinalFit, History, Problem
from graphcal.calibration.result import Calibration, CalibrationResult, drive_of
from graphcal.calibration.returns import Estimate, initial_estimate
from graphcal.calibration.static_sensor import halves_over_draws, pair_draws, soft_over_draws
from graphcal.calibration.unseen_controls import unseen_controls
from graphcal.calibration.verdict import RIGID_REASON, Motion, verdict
from graphcal.calibration.weak_directions import WeakDirections, seen_weakly
from graphcal.common.cluster import IN_PROCESS, TaskMap, open_task_map
from graphcal.common.errors import CalibrationError
from graphcal.common.progress import status
from graphcal.recording.directory import Recording

TILE_M = 50.0  # the tiles of a calibration spread over a cluster when no size is set [m]
HELD_REASON = "held at its nominal value (setting hold, or a static sensor's checks)"


def calibrate(recording: Recording, config: CalibrationConfig | None = None, quiet: bool = False,
              dask: str | None = None, checkpoint: str | Path | None = None) -> CalibrationResult:
    """Estimate what config.mode asks for (intrinsics, extrinsic, trajectory corrections, or successive
    stages) from the recording alone; every estimated parameter gets a 1-sigma, and what the data cannot
    see, or see only weakly, is held at its nominal value and named with its reason.

    dask: where the tiles' features and pairs are computed (graphcal.common.cluster: "local", "local:N" or a
    scheduler address such as "tcp://HOST:PORT"); the factor graph stays here. Tiles of
    association.tile_m [m] (TILE_M when not set): the result equals the one computed here with the same tiles.

    checkpoint: a file (graphcal.calibration.checkpoint) the calibration's state is saved to after each step and
    each outer iteration. A calibration started with the checkpoint an interrupted one of the same recording and
    settings left resumes from its last outer iteration, with the phase, gate, J curve and features it had: it
    ends with the uninterrupted calibration's outer iterations and estimate. The file is removed when the
    calibration ends, with a result or refused."""
    config = config or CalibrationConfig()
    if dask is not None and config.association.tile_m is None:
        config = config.with_settings(association={"tile_m": TILE_M})
    saved = None if checkpoint is None else Checkpoint.of(checkpoint, recording, config)
    state = None if saved is None else saved.load()
    # the block factors' matrix products are modest and run one at a time inside GTSAM's callbacks: BLAS
    # threads there only spin against open3d's and GTSAM's (measured 20x slower on a loaded 2-core machine)
    with threadpool_limits(limits=1, user_api="blas"), open_task_map(dask) as task_map:
        try:
            result = CalibrationPipeline(recording, config, quiet, task_map, saved, state).run()
        except CalibrationError:
            if saved is not None:
                saved.remove()
            raise
    if saved is not None:
        saved.remove()
    return result


def resumable(step):
    """A step of CalibrationPipeline.run that a resumed calibration skips when its checkpoint has it done (the
    steps are counted as run enters them); the state is saved when it ends."""

    @functools.wraps(step)
    def run_unless_done(self: CalibrationPipeline, *args, **kwargs):
        self.entered += 1
        if self.entered <= self.state.done:
            return
        step(self, *args, **kwargs)
        self.state.done, self.state.inside, self.state.features_at, self.state.window = self.entered, None, None, ()
        self.save()

    return run_unless_done


class CalibrationPipeline:
    """The steps of one calibration (run lists them) and what they share: the problem, the state (the estimate,
    the history of outer iterations, the weak directions held: checkpoint.PipelineState, saved to the checkpoint
    when there is one), the seconds of each step."""

    def __init__(self, recording: Recording, config: CalibrationConfig, quiet: bool, task_map: TaskMap = IN_PROCESS,
                 checkpoint: Checkpoint | None = None, resumed: PipelineState | None = None):
        self.recording, self.quiet, self.checkpoint = recording, quiet, checkpoint
        self.started, self.timings = time.perf_counter(), {}
        self.problem = self.timed("prepare", Problem.of, recording, config, task_map)
        controls = len(self.problem.full.control_times_s)
        if resumed is not None and len(resumed.estimate.corrections) != controls:  # placed by another graphcal
            raise checkpoint.of_another([f"trajectory controls {len(resumed.estimate.corrections)} (now {controls})"])
        self.state = resumed or PipelineState(initial_estimate(recording, self.problem.full))
        self.timings |= {name: seconds for name, seconds in self.state.timings.items() if name != "prepare"}
        self.history = History(self.state.rows)
        self.weak = WeakDirections.none(self.problem.layout())
        if self.state.weak_basis is not None:
            self.weak = replace(self.weak, basis=self.state.weak_basis, eigenvalues=self.state.weak_eigenvalues)
        self.entered = 0  # resumable steps entered so far
        self.halves = None

    @property
    def estimate(self) -> Estimate:
        return self.state.estimate

    @estimate.setter
    def estimate(self, estimate: Estimate) -> None:
        self.state.estimate = estimate

    def run(self) -> CalibrationResult:
        self.fix_the_pairs_of_a_static_sensor()
        self.hold_what_a_static_sensor_cannot_tie_to_itself()
        # what the data cannot see, or see only weakly, is found at the start (held through the coarse
        # phase), at the switch to the fine phase (held from there on) and at the end (if it adds some,
        # they are held and the fine phase runs again): held at nominal wherever it is found
        self.find_weak_directions("coarse", "weak directions at the start")
        self.solve(last=("coarse",), stall=self.can_start_again())
        self.start_again_holding_the_intrinsics_if_the_coarse_phase_stuck()
        self.find_weak_directions("fine", "weak directions, fine phase")
        self.solve(last=("fine",), first=len(self.problem.stages) - 1)
        self.find_weak_directions("fine", "weak directions at the end", grow=True)
        self.solve_again_if_more_are_weak(self.state.grown)
        # the final fit's sigmas that count each return's noise once can find weak what the model's information does
        # not: held too, the fine phase again and its final fit. Made even where a resumed run skips the step: its
        # features are those the fine phase after it starts from (skipped, a resumed run's last J moved by 7e-4)
        final = self.final_fit()
        self.find_parameters_seen_weakly(final)
        self.solve_again_if_more_are_weak(bool(self.state.seen_weakly), ", seen weakly held")
        return self.result(self.final_fit() if self.state.seen_weakly else final)

    def timed(self, name: str, work, *args, spinner: bool = True):
        """work(*args), its seconds added to the step `name`'s; on a terminal a spinner names the step (spinner=False:
        the work draws its own progress bar)."""
        mark = time.perf_counter()
        with status(f"calibrating: {name}", self.quiet) if spinner else nullcontext():
            out = work(*args)
        self.timings[name] = self.timings.get(name, 0.0) + time.perf_counter() - mark
        return out

    def save(self) -> None:
        """The state to the checkpoint (when there is one), with the seconds spent so far."""
        if self.checkpoint is not None:
            self.state.rows, self.state.timings = self.history.rows, self.timings
            self.state.weak_basis, self.state.weak_eigenvalues = self.weak.basis, self.weak.eigenvalues
            self.state.seconds += time.perf_counter() - self.started
            self.started = time.perf_counter()
            self.checkpoint.save(self.state)

    def fix_the_pairs_of_a_static_sensor(self) -> None:
        """A static sensor's pairs and normals are made once, at the start (association.fixed)."""
        if self.problem.settings.association.fixed:
            start = initial_estimate(self.recording, self.problem.full)
            self.problem = replace(self.problem, fixed_pairs=self.problem.associate(start))

    def hold_what_a_static_sensor_cannot_tie_to_itself(self) -> None:
        """The static checks (static.hold_soft, static.check_halves) judge the intrinsics left free (by
        default a static sensor holds them all), at the start."""
        problem, static = self.problem, self.problem.settings.static
        if not ((static.hold_soft or static.check_halves) and problem.estimated[0]
                and problem.priors.free_intrinsics(problem.fixed_fibre).any()):
            return
        start = initial_estimate(self.recording, problem.full)
        draws = self.timed("pair draws", pair_draws, problem, start, problem.associate(start))
        if static.hold_soft:
            self.problem = self.problem.holding(self.timed("soft parameters", soft_over_draws, self.problem,
                                                           start, draws))
        if static.check_halves:
            self.halves = self.timed("azimuth halves", halves_over_draws, self.problem, start, draws)
            self.problem = self.problem.holding(list(self.halves.held))

    @resumable
    def find_weak_directions(self, phase: Phase, name: str, grow: bool = False) -> None:
        """At the estimate, on the pairs of a phase: at the start the coarse phase's (the strict gates would keep
        few pairs of a start a few centimetres off), else the strict ones. grow: added to those held (grown says
        whether that held more), else in their place."""
        found = self.timed(name, self.problem.in_phase(phase).weak_directions, self.estimate)
        if grow:
            union = self.weak.union(found)
            self.state.grown = union.basis.shape[1] > self.weak.basis.shape[1]
            found = union if self.state.grown else self.weak
        self.weak = found

    @resumable
    def find_parameters_seen_weakly(self, final: FinalFit) -> None:
        """The parameters whose sigmas at the final fit, each return's noise counted once, leave them weak
        (weak_directions.seen_weakly; none without those sigmas), added to the weak directions held; those already
        held or named, and a static sensor's extrinsic (its whole cloud moves rigidly with it: named so by result),
        passed over."""
        problem = self.problem
        layout = problem.layout()
        passed = {*problem.held, *self.weak.named()}
        if problem.full.static:
            passed |= {f"extrinsic.{name}" for name in EXTRINSIC_NAMES}
        self.state.seen_weakly = ({} if final.shared_returns is None
                                  else seen_weakly(final.shared_returns, layout, passed))
        if self.state.seen_weakly:
            self.weak = self.weak.union(WeakDirections.along(list(self.state.seen_weakly), layout))

    def solve_again_if_more_are_weak(self, grown: bool, label: str = ", weak directions held") -> None:
        """When grown: the last stage's fine phase again, the weak directions added held too: it goes on from the fine
        phase's J curve (Problem.fit's plateau_from)."""
        if grown:
            stage = self.problem.stages[-1]
            energies = tuple(row["energy_cm2"] for row in self.history.rows
                             if row["mode"] == stage and row["phase"] == "fine")
            self.solve(last=("fine",), first=len(self.problem.stages) - 1, label=label, plateau_from=energies)

    def final_fit(self) -> FinalFit:
        """The final fit at the estimate, what the settings hold set to nominal first (Problem.final)."""
        self.estimate = self.problem.priors.hold_at_nominal(self.estimate, self.problem.nominal)
        return self.timed("final fit and marginals", self.problem.final, self.estimate, None, True)

    def can_start_again(self) -> bool:
        """Whether a coarse phase that stops on its cap or stalls has a remedy: the trajectory and the intrinsics
        estimated (start_again_holding_the_intrinsics_if_the_coarse_phase_stuck)."""
        return bool(self.problem.estimated[0] and self.problem.estimated[2])

    def start_again_holding_the_intrinsics_if_the_coarse_phase_stuck(self) -> None:
        """When the trajectory is estimated beside the intrinsics and the coarse phase stopped on its cap or stalled
        (Problem.fit's stall: its J flat at its full gate for stopping.plateau_iterations outer iterations), its pairs,
        made with gates up to a metre about returns an INS still off by its error placed, let the intrinsics' weak
        directions take up what the corrections had not yet (measured: sim6_turn at full size, level head, 0.35 m
        piecewise INS error, 1 M returns: capped at 60 outer iterations with the upward rings slid by 2-3 deg, the
        fine phase then converged with four rings collapsed on the horizon). The coarse phase runs again from the
        start with every intrinsic held at nominal (there: done in 6 outer iterations, and the fine phase, the
        intrinsics freed, converges at J's floor). Only then: from the start a drive that converges is better off
        with them free (dev/open-questions.md). Decided from the history's rows of the first coarse phase (labelled
        with the stage alone), which a resumed run has whether it stopped inside the coarse phase run again or after it:
        the same steps run in the same order."""
        problem, stage = self.problem, self.problem.stages[-1]
        stuck = any(row["mode"] == stage and row["phase"] == "coarse" and row["stop"] in ("cap", "stalled")
                    for row in self.history.rows)  # the first coarse phase's rows; a resumed run has them too
        if not (self.can_start_again() and stuck):
            return
        intrinsics = tuple(f"fibre_{fibre}.{name}" for fibre in range(problem.full.sensor.n_fibres)
                           for name in INTRINSIC_NAMES)
        self.solve(last=("coarse",), label=", intrinsics held", hold=intrinsics, from_start=True)

    @resumable
    def solve(self, last: tuple[Phase, ...], first: int = 0, label: str = "",
              plateau_from: tuple[float, ...] = (), hold: tuple[str, ...] = (), from_start: bool = False,
              stall: bool = False) -> None:
        """The stages from `first` one by one (successive modes stay successive), the last one's phases `last`
        only, the weak directions set back to and held at nominal, the parameters named in `hold` held at nominal
        too; plateau_from: the last stage's J curve this solve goes on from (Problem.fit); from_start: from the
        initial estimate, not the current one; stall: the last stage's coarse phase stops once it stalls
        (Problem.fit). Resumed (state.inside): from the stage and outer iteration the
        checkpoint stopped at."""
        if from_start and self.state.inside is None:  # resumed inside it, the checkpoint's estimate goes on
            self.estimate = initial_estimate(self.recording, self.problem.full)
        self.estimate = self.back_to_nominal(self.estimate)
        stages, cap, used = self.problem.stages, self.problem.settings.stopping.max_outer_iterations, self.state.used
        start, done = self.state.inside or (first, 0)
        for k, stage in enumerate(stages[start:], start):
            planned = last if k == len(stages) - 1 else PHASES
            ran = done if k == start else 0  # outer iterations of this stage the checkpoint has
            left = cap - (used.get(stage, 0) if planned == ("fine",) else 0)
            before, rows = len(self.history.rows) - ran, self.history.rows
            if ran and (rows[-1]["stop"] or left <= ran):  # the checkpoint was saved on the stage's last iteration
                rows[-1]["stop"] = rows[-1]["stop"] or "cap"
                used[stage] = ran
                continue

            def saved_each_iteration(estimate: Estimate, features_at: Estimate | None, window: tuple, k=k,
                                     before=before) -> None:
                self.estimate, self.state.inside = estimate, (k, len(self.history.rows) - before)
                self.state.features_at, self.state.window = features_at, window
                self.save()

            problem = self.problem.in_stage(stage).holding(list(hold)).locking(self.weak)
            self.estimate = self.timed(f"solve {stage}{label} ({', '.join(planned)})",
                                       problem.fit, self.estimate, self.history, stage + label, planned, left,
                                       self.quiet, saved_each_iteration if self.checkpoint else None, ran,
                                       self.state.features_at if ran else None,
                                       plateau_from if k == len(stages) - 1 else (), self.state.window if ran else (),
                                       stall and k == len(stages) - 1, spinner=False)
            used[stage] = len(self.history.rows) - before

    def back_to_nominal(self, estimate: Estimate) -> Estimate:
        offsets, extrinsic = self.weak.reset_to_nominal(estimate.offsets, estimate.extrinsic, self.problem.nominal)
        return replace(estimate, offsets=offsets, extrinsic=extrinsic)

    def result(self, final: FinalFit) -> CalibrationResult:
        """The calibration, checked (calibration/checks.py), with what it names and why (the weak directions, the
        trajectory corrections the data do not see: unseen_controls.py), and the one-line verdict on what the drive
        could not show (verdict.py)."""
        problem, estimate = self.problem, self.estimate
        data, config, estimated = problem.full, problem.settings, problem.estimated
        held = list(problem.held)
        gauges = config.priors.gauges(data.sensor.reference_fibre)
        named_held = [name for name in held if name not in gauges]  # held, not named: the gauge is no finding
        reasons = {name: HELD_REASON for name in named_held}
        reasons |= {name: reason for name, reason in self.weak.named().items() if name not in held}
        reasons |= self.state.seen_weakly
        if estimated[2]:
            reasons |= unseen_controls(final.sigmas().controls, data.control_times_s,
                                       problem.config.trajectory.deformation, problem.config.weighting.sigma0_m)
        unobservable = named_held + [name for name in reasons if name not in held]
        self.check(final, unobservable)
        if estimated[2]:
            unobservable += list(TRAJECTORY_GAUGE[:2 if config.trajectory.pose_corrections else 1])
        if data.static:  # whatever the mode: the whole cloud moves rigidly with the extrinsic and the trajectory
            rigid = [f"extrinsic.{n}" for n in EXTRINSIC_NAMES if f"extrinsic.{n}" not in unobservable]
            unobservable += rigid + [name for name in TRAJECTORY_GAUGE if name not in unobservable]
            held += rigid
            reasons |= {name: RIGID_REASON for name in rigid}
        shares = self.weak.held_shares()
        coarse = imprecise(final.sigmas(shares), config.accuracy,
                           {*unobservable, *held})
        reasons |= coarse
        calibration = Calibration(data.sensor.model, data.sensor.reference_fibre, estimate, data.control_times_s,
                                  tuple(unobservable), tuple(held), reasons, drive_of(self.recording), tuple(coarse))
        return CalibrationResult(calibration, final.uncertainty, estimated, self.history.rows,
                                 data.rows[final.pairs.index_p], final.residual_m, final.pairs.weight, config,
                                 self.state.seconds + time.perf_counter() - self.started, self.timings,
                                 halves=None if self.halves is None else self.halves.to_yaml_dict(),
                                 shared_returns_uncertainty=final.shared_returns,
                                 cluster_robust_uncertainty=final.cluster_robust, held_shares=shares,
                                 verdict=verdict(unobservable, reasons, Motion.of(data.R_nav, data.X_nav),
                                                 tuple(coarse)),
                                 trajectory_noise=self.recording.world.white_noise,
                                 ins_steps_s=data.steps_s if estimated[2] else data.steps_s[:0])

    def check(self, final: FinalFit, unobservable: list[str]) -> None:
        """Refuse a result that is not one (CalibrationError, exit code 3)."""
        problem, estimate, rows = self.problem, self.estimate, self.history.rows
        data, settings = problem.full, problem.settings
        where = str(self.recording.path or self.recording.name)
        check_energy_fell(rows, where)
        if settings.stopping.refuse_unconverged:
            check_converged(rows, where)
        if problem.estimated[0]:
            check_fibres_apart(data.sensor.elevation_deg, estimate.offsets[:, 2], where)
            check_rings_in_order(data.sensor.elevation_deg, estimate.offsets[:, 2], settings.priors.intrinsic_angle_deg,
                                 where)
        if settings.stopping.refuse_outside_priors:
            check_within_priors(estimate, problem.nominal, problem.layout(), unobservable, where)
        # one viewpoint (static): the scene's shape between the rings stays in J (docs/reference/math.md); an
        # estimate accepted unconverged: its J says nothing of the model
        if not data.one_viewpoint and settings.stopping.refuse_unconverged:
            check_energy_explained(rows[-1]["energy_after_cm2"], final.expected_energy_cm2, data.range_noise_m, where)

