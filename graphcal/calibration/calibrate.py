"""graphcal.calibrate: the pipeline of one calibration, one line per step."""

from __future__ import annotations

import time
from functools import partial

import gtsam
import numpy as np
from threadpoolctl import threadpool_limits

from graphcal.association import Correspondences
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
    build_graph,
    control_prior_sigma,
    hold_at_nominal,
    holding,
    make_blocks,
    solve_stage,
    strict_pairs,
)
from graphcal.calibration.static_sensor import free_intrinsics, halves_over_draws, pair_draws, soft_over_draws
from graphcal.errors import CalibrationError, ConfigError
from graphcal.intrinsics import offsets_to_file_units
from graphcal.recording import Recording


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
    config = config.for_sensor(data.static, data.range_noise_m)
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

    def run_stages(estimate: Estimate, priors: Priors, label: str = "", last: tuple[str, ...] = PHASES,
                   first: int = 0) -> Estimate:
        """The stages from `first` one by one (successive modes stay successive), the last one's phases `last` only."""
        for k, stage in enumerate(stages[first:], first):
            phases = last if k == len(stages) - 1 else PHASES
            left = config.max_outer_iterations - (used.get(stage, 0) if phases == ("fine",) else 0)
            before = len(history.rows)
            estimate = timed(f"solve {stage}{label} ({', '.join(phases)})", solve_stage, data, estimate, config,
                             stage + label, ESTIMATES[stage], nominal, priors, history, quiet, fixed_pairs, phases,
                             cache, left)
            used[stage] = len(history.rows) - before
        return estimate

    # at the switch to the fine phase the Marginals name what the data cannot observe: held at nominal
    # from there, it cannot drag the others through the fine phase (docs/math.md "Observability")
    estimate = run_stages(estimate, priors, last=("coarse",))
    probe = timed("observability", final_fit, data, estimate, config, estimated, nominal, priors, fixed_pairs, cache)
    named = [name for name in probe.uncertainty.unobservable() if name not in held]
    label = ""
    if named:
        priors, label = holding(priors, named), ", unobservable held"
        estimate = hold_at_nominal(estimate, priors, nominal)
        if len(stages) > 1:
            estimate = run_stages(estimate, priors, label, last=("coarse",))
    estimate = hold_at_nominal(run_stages(estimate, priors, label, last=("fine",), first=len(stages) - 1), priors,
                               nominal)
    final = timed("final fit and marginals", final_fit, data, estimate, config, estimated, nominal, priors,
                  fixed_pairs, cache, True)
    late = [name for name in final.uncertainty.unobservable() if name not in held + named]
    if late:  # seen only at the fine phase's pairs: hold them too and run the stages again
        priors = holding(priors, late)
        estimate = hold_at_nominal(run_stages(hold_at_nominal(estimate, priors, nominal), priors, ", unobservable held"),
                                   priors, nominal)
        final = timed("final fit and marginals, unobservable held", final_fit, data, estimate, config, estimated,
                      nominal, priors, fixed_pairs, cache, True)
    unobservable = held + named + late
    check_energy_fell(history.rows, recording)
    if estimated[0]:
        check_fibres_apart(data.sensor.elevation_deg, estimate.offsets[:, 2], recording)
    if estimated[2]:
        unobservable += list(TRAJECTORY_GAUGE[:2 if config.pose_corrections else 1])
    if data.static:  # whatever the mode: the whole cloud moves rigidly with the extrinsic and the trajectory
        unobservable += [name for name in (*(f"extrinsic.{n}" for n in EXTRINSIC_NAMES), *TRAJECTORY_GAUGE)
                         if name not in unobservable]
    calibration = Calibration(data.sensor.model, data.sensor.reference_fibre, estimate, data.control_times_s,
                              tuple(unobservable))
    return CalibrationResult(calibration, final.uncertainty, estimated, history.rows, data.rows[final.pairs.index_p],
                             final.residual_m, final.pairs.weight, config, time.perf_counter() - started, timings,
                             halves=None if halves is None else halves.to_yaml_dict(),
                             shared_returns_uncertainty=final.shared_returns)


# calibrated elevations spread over less than this fraction of the nominal ones: the fibres collapsed
COLLAPSE_RATIO = 0.5
# J at the end over J at the start above which a run diverged
DIVERGED_RATIO = 2.0


def check_fibres_apart(elevation_deg: np.ndarray, d_elevation_rad: np.ndarray, recording: Recording) -> None:
    """Raise CalibrationError when the fibres' calibrated elevations have collapsed together.

    The self-consistency energy has a trivial minimum: fibres that sweep one cone see the same
    points, and every point-to-plane distance between them vanishes. A run that starts far from
    the truth, or stops early, or whose scene leaves it a direction it cannot see (a level head
    over flat ground, docs/math.md), can slide towards it (J falls while the cloud gets worse); no
    real sensor has its beams' spread halved, so such a result is refused, not returned."""
    calibrated = elevation_deg + np.degrees(d_elevation_rad)
    nominal_spread, spread = float(np.std(elevation_deg)), float(np.std(calibrated))
    if spread < COLLAPSE_RATIO * nominal_spread:
        raise CalibrationError(
            f"{recording.path or recording.name}: the fibres' calibrated elevations collapsed together (spread "
            f"{spread:.2f} deg against {nominal_spread:.2f} deg nominal): a degenerate minimum where neighbouring "
            "fibres coincide, not a calibration; start closer to the truth (smaller offsets), allow more outer "
            "iterations (max_outer_iterations), or tighten the angle prior (intrinsic_sigma_angle_deg). A level "
            "head over flat ground slides there even from the truth: its fibres that see only the ground can rise "
            "together unseen (docs/math.md); calibrate its intrinsics from a drive with the head pitched or with "
            "objects at many heights")


def check_energy_fell(history: list[dict], recording: Recording) -> None:
    """Raise CalibrationError when J ends DIVERGED_RATIO times above where it started: the outer
    loop diverged (its association kept finding worse pairs), and the estimate makes the cloud less
    consistent than the nominal model did. J's pairs change with the gate and the phase, so a
    smaller rise (a run started at the truth whose gate opens) is not taken for divergence."""
    start, end = history[0]["energy_cm2"], history[-1]["energy_after_cm2"]
    if end > DIVERGED_RATIO * start:
        raise CalibrationError(
            f"{recording.path or recording.name}: the calibration diverged (J {start:.3g} cm2 at the start, "
            f"{end:.3g} cm2 at the end): the nominal model fits this recording better than the estimate; tighten "
            "the priors (intrinsic_sigma_range_m, intrinsic_sigma_angle_deg), hold what the drive cannot observe "
            "(hold), or use a recording with more surfaces and motion")


class FinalFit:
    """Association at the final estimate (strict settings), per-pair residuals, the marginals of the
    undamped graph and, for pairs whitened by the range noise, the sigmas with each return's noise
    counted once over the pairs that share it (shared_returns.py; None otherwise)."""

    def __init__(self, pairs, residual_m: np.ndarray, uncertainty: Uncertainty,
                 shared_returns: Uncertainty | None = None):
        self.pairs, self.residual_m, self.uncertainty = pairs, residual_m, uncertainty
        self.shared_returns = shared_returns


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
    return FinalFit(pairs, residual, sigmas(Marginals(graph, values)), shared)


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
