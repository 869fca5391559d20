"""graphcal.calibrate: the pipeline of one calibration, one line per step."""

from __future__ import annotations

import time
from dataclasses import replace

import gtsam
import numpy as np
from threadpoolctl import threadpool_limits

from graphcal.association import Correspondences
from graphcal.calibration.config import ESTIMATES, STAGES, CalibrationConfig, held_names
from graphcal.calibration.observability import (
    CONTROL_NAMES,
    EXTRINSIC_NAMES,
    INTRINSIC_NAMES,
    POSE_TO_FILE_UNITS,
    TRAJECTORY_GAUGE,
    Marginals,
    Uncertainty,
    intrinsic_sigmas,
    pose_sigmas,
    soft_parameters,
)
from graphcal.calibration.problem import (
    Estimate,
    ReturnData,
    initial_estimate,
    prepare,
    world_at,
)
from graphcal.calibration.result import Calibration, CalibrationResult
from graphcal.calibration.solve import (
    HELD_SIGMA,
    Association,
    E,
    History,
    I,
    Priors,
    X,
    build_graph,
    control_prior_sigma,
    features_at,
    hold_at_nominal,
    solve_stage,
)
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
    data = prepare(recording, config.control_interval_s, config.max_points, np.random.default_rng(config.seed))
    config = config.for_sensor(data.static)
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

    # a static sensor's pairs are made once, at the start (config.fixed_association; docs/math.md)
    fixed_pairs = strict_pairs(data, estimate, config)[1] if config.fixed_association else None
    if config.hold_soft and estimated[0]:
        soft = timed("soft parameters", soft_intrinsics, data, estimate, config, nominal, priors, fixed_pairs)
        held, priors = held + soft, holding(priors, soft)
    if config.check_halves and estimated[0]:
        halves = timed("azimuth halves", unreproducible_intrinsics, data, estimate, config, nominal, priors,
                       fixed_pairs)
        held, priors = held + halves, holding(priors, halves)

    def run_stages(estimate: Estimate, priors: Priors, label: str = "") -> Estimate:
        for stage in stages:
            estimate = timed(f"solve {stage}{label}", solve_stage, data, estimate, config, stage + label,
                             ESTIMATES[stage], nominal, priors, history, quiet, fixed_pairs)
        return estimate

    estimate = run_stages(estimate, priors)
    final = timed("final fit and marginals", final_fit, data, estimate, config, estimated, nominal, priors,
                  fixed_pairs)
    unobservable = [name for name in final.uncertainty.unobservable() if name not in held]
    if unobservable:  # hold them at nominal and run the stages again: they must not drag the others
        priors = holding(priors, unobservable)
        # stage by stage still: successive modes must not turn joint here
        estimate = hold_at_nominal(run_stages(hold_at_nominal(estimate, priors, nominal), priors, ", unobservable held"),
                                   priors, nominal)
        final = timed("final fit and marginals, unobservable held", final_fit, data, estimate, config, estimated,
                      nominal, priors, fixed_pairs)
    unobservable = held + unobservable
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
                             final.residual_m, final.pairs.weight, config, time.perf_counter() - started, timings)


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
    """Association at the final estimate (strict settings), per-pair residuals and the marginals
    of the undamped graph."""

    def __init__(self, pairs, residual_m: np.ndarray, uncertainty: Uncertainty):
        self.pairs, self.residual_m, self.uncertainty = pairs, residual_m, uncertainty


def strict_pairs(data: ReturnData, estimate: Estimate, config: CalibrationConfig):
    """(world points [m], pairs) at an estimate with the strict settings of the fine phase."""
    fine = config.fine()
    points = world_at(data, estimate, config.pose_corrections)
    return points, Association.of(data, fine).pairs(points, data.fibre, features_at(points, config), fine.fine_gate_m,
                                                    fine)


def soft_intrinsics(data: ReturnData, estimate: Estimate, config: CalibrationConfig, nominal: gtsam.Pose3,
                    priors: Priors, pairs: Correspondences | None = None) -> list[str]:
    """Names of the intrinsics not yet held that the data at the estimate (strict association)
    determine worse than config.firm_sigma_m / firm_sigma_deg, alone or in combination
    (observability.soft_parameters on the graph's information; the weak priors add about
    (firm / prior sigma)^2 = 1e-3 of the threshold to it). On a static sensor whose reference fibre
    sees only far objects, the common vertical offset of the fibres that see the ground is such a
    combination: no pair ties it to the reference (docs/math.md). pairs: those to judge by (None: the
    strict association at the estimate)."""
    pairs = strict_pairs(data, estimate, config)[1] if pairs is None else pairs
    graph, values = build_graph(data, estimate, pairs, config, (True, False, False), nominal, priors, damped=False)
    fibres = [f for f in range(data.sensor.n_fibres) if f != data.sensor.reference_fibre]
    information, _ = graph.linearize(values).hessian(gtsam.Ordering([I(f) for f in fibres]))
    free = np.flatnonzero(priors.intrinsic[fibres].ravel() > HELD_SIGMA)
    firm_rad = np.radians(config.firm_sigma_deg)
    firm = np.tile([config.firm_sigma_m, firm_rad, firm_rad, config.firm_sigma_m], len(fibres))
    soft = free[soft_parameters(information[np.ix_(free, free)], firm[free])]
    return [f"fibre_{fibres[i // 4]}.{INTRINSIC_NAMES[i % 4]}" for i in soft]


# estimates from the two azimuth halves differing by more than this many firm sigmas: not the sensor's
HALVES_RATIO = 3.0


def unreproducible_intrinsics(data: ReturnData, estimate: Estimate, config: CalibrationConfig, nominal: gtsam.Pose3,
                              priors: Priors, pairs: Correspondences | None = None) -> list[str]:
    """Names of the intrinsics not yet held whose estimates from the two azimuth halves of the scene
    differ by more than HALVES_RATIO times config.firm_sigma_m / firm_sigma_deg. A sensor's offset is
    the same in every direction; but a static head sees each surface from one viewpoint, and an
    offset can also fit the shape of the surfaces between its rings (docs/math.md): fitted on the
    pairs whose p has an encoder azimuth in [0, 180) deg, then on those in [180, 360), such an offset
    comes out differently. Each half is solved as the intrinsic stage on its pairs, held fixed
    (pairs: None: the strict association at the estimate), and again with what disagreed held,
    until the halves agree on every parameter left: holding one can move the others."""
    pairs = strict_pairs(data, estimate, config)[1] if pairs is None else pairs
    first = np.mod(data.azimuth_rad[pairs.index_p], 2 * np.pi) < np.pi
    firm_rad = np.radians(config.firm_sigma_deg)
    firm = np.array([config.firm_sigma_m, firm_rad, firm_rad, config.firm_sigma_m])
    names = []
    while True:
        fits = [solve_stage(data, estimate, config, "intrinsic, azimuth half", ESTIMATES["intrinsic"], nominal,
                            priors, History(), True, pairs.take(half)) for half in (first, ~first)]
        apart = (np.abs(fits[0].offsets - fits[1].offsets) / firm > HALVES_RATIO) & (priors.intrinsic > HELD_SIGMA)
        apart[data.sensor.reference_fibre] = False
        if not apart.any():
            return names
        more = [f"fibre_{i}.{INTRINSIC_NAMES[k]}" for i, k in zip(*np.nonzero(apart))]
        names, priors = names + more, holding(priors, more)


def final_fit(data: ReturnData, estimate: Estimate, config: CalibrationConfig, estimated, nominal: gtsam.Pose3,
              priors: Priors, pairs: Correspondences | None = None) -> FinalFit:
    """The fit at the estimate on the given pairs (None: the strict association at the estimate)."""
    if pairs is None:
        points, pairs = strict_pairs(data, estimate, config)
    else:
        points = world_at(data, estimate, config.pose_corrections)
    residual = np.einsum("ni,ni->n", pairs.normal, points[pairs.index_p] - points[pairs.index_m])
    graph, values = build_graph(data, estimate, pairs, config, estimated, nominal, priors, damped=False)
    return FinalFit(pairs, residual, uncertainty(Marginals(graph, values), data, estimate, config, estimated,
                                                 nominal, priors,
                                                 control_prior_sigma(config, float(pairs.weight.sum()))))


def uncertainty(marginals: gtsam.Marginals, data: ReturnData, estimate: Estimate, config: CalibrationConfig,
                estimated, nominal: gtsam.Pose3, priors: Priors, control_sigma: float) -> Uncertainty:
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


def holding(priors: Priors, names: list[str]) -> Priors:
    """Priors with the named parameters' sigmas shrunk to HELD_SIGMA (held at nominal)."""
    intrinsic, extrinsic, control = priors.intrinsic.copy(), priors.extrinsic.copy(), priors.control_held.copy()
    for name in names:
        owner, parameter = name.split(".")
        index = int(owner.split("_")[1]) if "_" in owner else 0
        if owner.startswith("fibre_"):
            intrinsic[index, INTRINSIC_NAMES.index(parameter)] = HELD_SIGMA
        elif owner == "extrinsic":
            extrinsic[EXTRINSIC_NAMES.index(parameter)] = HELD_SIGMA
        else:
            column = CONTROL_NAMES.index(parameter) - (6 - control.shape[1])
            control[index, column] = True
    return replace(priors, intrinsic=intrinsic, extrinsic=extrinsic, control_held=control)
