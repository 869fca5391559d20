"""graphcal.calibrate: the pipeline of one calibration, one line per step."""

from __future__ import annotations

import time
from dataclasses import replace
from functools import partial

import gtsam
import numpy as np
from threadpoolctl import threadpool_limits

from graphcal.calibration.association import Correspondences
from graphcal.calibration.config import ESTIMATES, STAGES, CalibrationConfig, held_names
from graphcal.calibration.observability import (
    EXTRINSIC_NAMES,
    POSE_TO_FILE_UNITS,
    TRAJECTORY_GAUGE,
    Marginals,
    Uncertainty,
    intrinsic_sigmas,
    pose_sigmas,
)
from graphcal.calibration.problem import (
    revisits,
    Estimate,
    ReturnData,
    initial_estimate,
    prepare,
    world_at,
)
from graphcal.calibration.result import Calibration, CalibrationResult
from graphcal.calibration.shared_returns import SharedReturnsCovariance
from graphcal.calibration.solve import (
    HELD_SIGMA,
    PHASES,
    E,
    FeatureCache,
    History,
    I,
    Priors,
    X,
    Association,
    build_graph,
    features_at,
    phase_data,
    control_prior_sigma,
    hold_at_nominal,
    holding,
    make_blocks,
    solve_stage,
    strict_pairs,
)
from graphcal.calibration.checks import (
    check_converged,
    check_energy_explained,
    check_energy_fell,
    check_fibres_apart,
    check_rings_in_order,
    check_within_priors,
)
from graphcal.calibration.weak_analysis import layout_of, weak_at
from graphcal.calibration.weak_directions import WeakDirections, lock_factor
from graphcal.calibration.static_sensor import free_intrinsics, halves_over_draws, pair_draws, soft_over_draws
from graphcal.common.errors import CalibrationError, ConfigError
from graphcal.recording.intrinsics import offsets_to_file_units
from graphcal.recording.directory import Recording


def calibrate(recording: Recording, config: CalibrationConfig | None = None, quiet: bool = False) -> CalibrationResult:
    """Estimate what config.mode asks for (intrinsics, extrinsic, trajectory corrections, or
    successive stages) from the recording alone; every estimated parameter gets a 1-sigma, and
    the parameters the data cannot observe are held at their nominal value and named."""
    # the block factors' matrix products are modest and run one at a time inside GTSAM's
    # callbacks: BLAS threads there only spin against open3d's and GTSAM's (measured 20x slower
    # on a loaded 2-core machine)
    with threadpool_limits(limits=1, user_api="blas"):
        return _calibrate(recording, config or CalibrationConfig(), quiet)


def _calibrate(recording: Recording, config: CalibrationConfig, quiet: bool) -> CalibrationResult:
    started = time.perf_counter()
    timings = {}  # stage -> seconds
    data = prepare(recording, config.control_interval_s, config.max_points, np.random.default_rng(config.seed),
                   range_noise_m=config.range_noise_m)
    config = config.for_sensor(data.static, data.range_noise_m, revisits(recording.world.poses))
    timings["prepare"] = time.perf_counter() - started
    estimate = initial_estimate(recording, data)
    nominal = estimate.extrinsic
    try:  # the settings allow any head's fibres: this recording's head may have fewer, or fix the one named
        held = held_names(config.hold, data.sensor.n_fibres, data.sensor.reference_fibre)
    except ConfigError as error:
        raise ConfigError(f"{recording.path or recording.name}: hold: {error} (sensor {data.sensor.model}, "
                          f"{data.sensor.n_fibres} fibres, reference fibre {data.sensor.reference_fibre})") from None
    priors = holding(Priors.of(config, data.sensor.n_fibres, len(data.control_times_s)), held)
    stages = STAGES.get(config.mode, (config.mode,))
    estimated = tuple(any(ESTIMATES[stage][k] for stage in stages) for k in range(3))
    history = History()

    def timed(name: str, work, *args):
        mark = time.perf_counter()
        out = work(*args)
        timings[name] = time.perf_counter() - mark
        return out

    cache = FeatureCache(config)
    # a static sensor's pairs are made once, at the start (config.fixed_association; docs/math.md)
    fixed_pairs = strict_pairs(data, estimate, config, cache)[1] if config.fixed_association else None
    halves = None
    # the static checks judge the intrinsics left free (by default a static sensor holds them all)
    if (config.hold_soft or config.check_halves) and estimated[0] and \
            free_intrinsics(priors, data.sensor.reference_fibre).any():
        start_pairs = strict_pairs(data, estimate, config, cache)[1] if fixed_pairs is None else fixed_pairs
        draws = timed("pair draws", pair_draws, data, estimate, config, start_pairs, cache)
        if config.hold_soft:
            soft = timed("soft parameters", soft_over_draws, data, estimate, config, nominal, priors, draws)
            held, priors = held + soft, holding(priors, soft)
        if config.check_halves:
            halves = timed("azimuth halves", halves_over_draws, data, estimate, config, nominal, priors, draws)
            held, priors = held + list(halves.held), holding(priors, halves.held)

    used = {}  # outer iterations each stage has run: n_max counts both phases of a stage
    layout = layout_of(data, priors, estimated, nominal)

    def run_stages(estimate: Estimate, weak: WeakDirections, label: str = "", last: tuple[str, ...] = PHASES,
                   first: int = 0) -> Estimate:
        """The stages from `first` one by one (successive modes stay successive), the last one's phases `last`
        only, the weak directions held at nominal."""
        for k, stage in enumerate(stages[first:], first):
            phases = last if k == len(stages) - 1 else PHASES
            left = config.max_outer_iterations - (used.get(stage, 0) if phases == ("fine",) else 0)
            before = len(history.rows)
            held_here = weak.restricted(*ESTIMATES[stage][:2])
            lock = lock_factor(held_here, [I(f) for f in held_here.layout.fibres],
                               E(0) if held_here.layout.extrinsic else None, nominal)
            estimate = timed(f"solve {stage}{label} ({', '.join(phases)})", solve_stage, data, estimate, config,
                             stage + label, ESTIMATES[stage], nominal, priors, history, quiet, fixed_pairs, phases,
                             cache, left, lock)
            used[stage] = len(history.rows) - before
        return estimate

    def weak_here(estimate: Estimate, phase: str) -> WeakDirections:
        """The weak directions at the estimate on the pairs of a phase: at the start the coarse phase's (the
        strict gates would keep few pairs of a start a few centimetres off), else the strict ones."""
        if fixed_pairs is not None:
            return weak_at(data, estimate, fixed_pairs, config.fine(), estimated, priors, layout)
        if phase == "fine":
            return weak_at(data, estimate, strict_pairs(data, estimate, config, cache)[1], config.fine(), estimated,
                           priors, layout)
        returns, settings = phase_data(data, config, phase)
        points = world_at(returns, estimate, config.pose_corrections)
        pairs = Association.of(returns, settings).pairs(points, returns.fibre, features_at(points, settings),
                                                        settings.gate_start_m, settings, None, phase)
        return weak_at(returns, estimate, pairs, settings, estimated, priors, layout)

    def back_to_nominal(estimate: Estimate, weak: WeakDirections) -> Estimate:
        offsets, extrinsic = weak.reset_to_nominal(estimate.offsets, estimate.extrinsic, nominal)
        return replace(estimate, offsets=offsets, extrinsic=extrinsic)

    # what the data cannot see, or see only weakly, is found at the start (held through the coarse phase), at
    # the switch to the fine phase (held from there on) and at the end (if it adds some, they are held and the
    # fine phase runs again): held at nominal wherever it is found (calibration/weak_directions.py)
    weak = timed("weak directions at the start", weak_here, estimate, "coarse")
    estimate = run_stages(estimate, weak, last=("coarse",))
    weak = timed("weak directions, fine phase", weak_here, estimate, "fine")
    estimate = run_stages(back_to_nominal(estimate, weak), weak, last=("fine",), first=len(stages) - 1)
    late = weak.union(timed("weak directions at the end", weak_here, estimate, "fine"))
    if late.basis.shape[1] > weak.basis.shape[1]:
        weak = late
        estimate = run_stages(back_to_nominal(estimate, weak), weak, ", weak directions held", last=("fine",),
                              first=len(stages) - 1)
    estimate = hold_at_nominal(estimate, priors, nominal)
    final = timed("final fit and marginals", final_fit, data, estimate, config, estimated, nominal, priors,
                  fixed_pairs, cache, True)
    reasons = {name: "held at its nominal value (setting hold, or a static sensor's checks)" for name in held}
    reasons |= {name: reason for name, reason in weak.named().items() if name not in held}
    unobservable = held + [name for name in reasons if name not in held]
    where = str(recording.path or recording.name)
    check_energy_fell(history.rows, where)
    if config.refuse_unconverged:
        check_converged(history.rows, where)
    if estimated[0]:
        check_fibres_apart(data.sensor.elevation_deg, estimate.offsets[:, 2], where)
        check_rings_in_order(data.sensor.elevation_deg, estimate.offsets[:, 2], config.intrinsic_sigma_angle_deg, where)
    check_within_priors(estimate, nominal, layout, unobservable, where)
    # one viewpoint (static): the scene's shape between the rings stays in J (docs/math.md); an estimate
    # accepted unconverged: its J says nothing of the model
    if not data.static and config.refuse_unconverged:
        check_energy_explained(history.rows[-1]["energy_after_cm2"], final.expected_energy_cm2, data.range_noise_m,
                               where)
    if estimated[2]:
        unobservable += list(TRAJECTORY_GAUGE[:2 if config.pose_corrections else 1])
    if data.static:  # whatever the mode: the whole cloud moves rigidly with the extrinsic and the trajectory
        rigid = [f"extrinsic.{n}" for n in EXTRINSIC_NAMES if f"extrinsic.{n}" not in unobservable]
        unobservable += rigid + [name for name in TRAJECTORY_GAUGE if name not in unobservable]
        held = held + rigid
        reasons |= {name: "a static sensor: the whole cloud moves rigidly with it" for name in rigid}
    calibration = Calibration(data.sensor.model, data.sensor.reference_fibre, estimate, data.control_times_s,
                              tuple(unobservable), tuple(held), reasons)
    return CalibrationResult(calibration, final.uncertainty, estimated, history.rows, data.rows[final.pairs.index_p],
                             final.residual_m, final.pairs.weight, config, time.perf_counter() - started, timings,
                             halves=None if halves is None else halves.to_yaml_dict(),
                             shared_returns_uncertainty=final.shared_returns)


class FinalFit:
    """Association at the final estimate (strict settings), per-pair residuals, the marginals of the
    undamped graph and, for pairs whitened by the range noise, the sigmas with each return's noise
    counted once over the pairs that share it (shared_returns.py; None otherwise), and the J [cm^2] the
    pairs' noise model predicts when they are whitened by the measured noise (None otherwise)."""

    def __init__(self, pairs, residual_m: np.ndarray, uncertainty: Uncertainty,
                 shared_returns: Uncertainty | None = None, expected_energy_cm2: float | None = None):
        self.pairs, self.residual_m, self.uncertainty = pairs, residual_m, uncertainty
        self.shared_returns, self.expected_energy_cm2 = shared_returns, expected_energy_cm2


def final_fit(data: ReturnData, estimate: Estimate, config: CalibrationConfig, estimated, nominal: gtsam.Pose3,
              priors: Priors, pairs: Correspondences | None = None, cache: FeatureCache | None = None,
              shared_returns: bool = False) -> FinalFit:
    """The fit at the estimate on the given pairs (None: the strict association at the estimate, its
    features from the cache when the cloud has not moved since); shared_returns: also the sigmas of
    shared_returns.py when the pairs are whitened by the range noise (pair_noise incidence, sigma0 the
    range noise) and no robust loss reweights them."""
    if pairs is None:
        points, pairs = strict_pairs(data, estimate, config, cache)
    else:
        points = world_at(data, estimate, config.pose_corrections)
    residual = np.einsum("ni,ni->n", pairs.normal, points[pairs.index_p] - points[pairs.index_m])
    blocks = make_blocks(data, estimate, pairs, config, estimated)
    graph, values = build_graph(data, estimate, pairs, config, estimated, nominal, priors, damped=False, blocks=blocks)
    sigmas = partial(uncertainty, data=data, estimate=estimate, config=config, estimated=estimated, priors=priors,
                     control_sigma=control_prior_sigma(config, float(pairs.weight.sum())))
    shared = None
    if shared_returns and config.pair_noise == "incidence" and config.robust == "none":
        shared = sigmas(SharedReturnsCovariance(graph, values, blocks, pairs, data, estimate, config.sigma0_m))
    expected = None
    if config.pair_noise == "incidence" and blocks:  # pairs whitened by the measured noise: J it predicts
        weight = np.concatenate([block.weight for _, block in blocks])
        sigma = np.concatenate([np.broadcast_to(block.sigma0_m, len(block.weight)) for _, block in blocks])
        expected = float((weight * sigma ** 2).sum() / weight.sum() * 1e4)
    return FinalFit(pairs, residual, sigmas(Marginals(graph, values)), shared, expected)


def uncertainty(marginals: gtsam.Marginals, data: ReturnData, estimate: Estimate, config: CalibrationConfig,
                estimated, priors: Priors, control_sigma: float) -> Uncertainty:
    """Posterior and prior sigmas in file units (m, deg) for every estimated parameter."""
    est_int, est_ext, est_traj = estimated
    n = data.sensor.n_fibres
    intrinsics = np.full((n, 4), np.nan)
    prior_int = offsets_to_file_units(priors.intrinsic)
    if est_int:
        for fibre in range(n):
            if fibre != data.sensor.reference_fibre:
                intrinsics[fibre] = intrinsic_sigmas(marginals, I(fibre))
    extrinsic = extrinsic_prior = None
    if est_ext:
        R = estimate.extrinsic.rotation().matrix()
        extrinsic = pose_sigmas(marginals.marginalCovariance(E(0)), R)
        extrinsic_prior = priors.extrinsic * POSE_TO_FILE_UNITS
    controls = controls_prior = None
    if est_traj:
        rows, prior_rows = [], []
        for c, correction in enumerate(estimate.corrections):
            cov = marginals.marginalCovariance(X(c))
            if config.pose_corrections:
                rows.append(pose_sigmas(cov, correction.rotation().matrix()))
            else:
                rows.append(np.r_[np.full(3, np.nan), np.sqrt(np.diag(cov))])
            held = np.r_[np.zeros(6 - priors.control_held.shape[1], bool), priors.control_held[c]]
            prior_rows.append(np.where(held, HELD_SIGMA, control_sigma) * POSE_TO_FILE_UNITS)
        controls, controls_prior = np.array(rows), np.array(prior_rows)
    return Uncertainty(intrinsics, prior_int, extrinsic, extrinsic_prior, controls, controls_prior)
