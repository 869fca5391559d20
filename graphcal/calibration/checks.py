"""A calibration graphcal refuses to return (CalibrationError, exit code 3), each with one plain line:
what went wrong, which parameters, and what data or setting would fix it."""

from __future__ import annotations

import gtsam
import numpy as np

from graphcal.calibration.weak_directions import Layout, tangent_about_nominal
from graphcal.common.errors import CalibrationError

# calibrated elevations spread over less than this fraction of the nominal ones: the fibres collapsed
COLLAPSE_RATIO = 0.5
# J at the end over J at the start above which a run diverged
DIVERGED_RATIO = 2.0


def check_fibres_apart(elevation_deg: np.ndarray, d_elevation_rad: np.ndarray, where: str) -> None:
    """Raise CalibrationError when the fibres' calibrated elevations have collapsed together.

    The self-consistency energy has a trivial minimum: fibres that sweep one cone see the same
    points, and every point-to-plane distance between them vanishes. A run that starts far from
    the truth, or stops early, or whose scene leaves it a direction it cannot see (a level head
    over flat ground, docs/reference/math.md), can slide towards it (J falls while the cloud gets worse); no
    real sensor has its beams' spread halved, so such a result is refused, not returned."""
    calibrated = elevation_deg + np.degrees(d_elevation_rad)
    nominal_spread, spread = float(np.std(elevation_deg)), float(np.std(calibrated))
    if spread < COLLAPSE_RATIO * nominal_spread:
        raise CalibrationError(
            f"{where}: the fibres' calibrated elevations collapsed together (spread "
            f"{spread:.2f} deg against {nominal_spread:.2f} deg nominal): a degenerate minimum where neighbouring "
            "fibres coincide, not a calibration; start closer to the truth (smaller offsets), allow more outer "
            "iterations (stopping.max_outer_iterations), or tighten the angle prior (priors.intrinsic_angle_deg). A level "
            "head over flat ground slides there even from the truth: its fibres that see only the ground can rise "
            "together unseen (docs/reference/math.md); calibrate its intrinsics from a drive with the head pitched or with "
            "objects at many heights")


def check_energy_fell(history: list[dict], where: str) -> None:
    """Raise CalibrationError when J ends DIVERGED_RATIO times above where it started: the outer
    loop diverged (its association kept finding worse pairs), and the estimate makes the cloud less
    consistent than the nominal model did. J's pairs change with the gate and the phase, so a
    smaller rise (a run started at the truth whose gate opens) is not taken for divergence."""
    start, end = history[0]["energy_cm2"], history[-1]["energy_after_cm2"]
    if end > DIVERGED_RATIO * start:
        raise CalibrationError(
            f"{where}: the calibration diverged (J {start:.3g} cm2 at the start, "
            f"{end:.3g} cm2 at the end): the nominal model fits this recording better than the estimate; tighten "
            "the priors (priors.intrinsic_range_m, priors.intrinsic_angle_deg), hold what the drive cannot observe "
            "(static.hold), or use a recording with more surfaces and motion")



# a free parameter further than this many prior sigmas from its nominal value slid there
PRIOR_SIGMAS = 5.0
# J at the end above this many times what the pairs' noise model predicts: the model misses something
ENERGY_EXCESS = 4.0


def check_converged(history: list[dict], where: str) -> None:
    """Raise when the last stage did not end converged in its fine phase: it stopped on the cap of outer
    iterations (stopping.max_outer_iterations) in the coarse phase (it never reached the basin) or in the
    fine phase (the estimate was still moving), or the cap left the fine phase no iteration; or when its last coarse
    phase (one run again, CalibrationPipeline's intrinsics held, is judged, not the one before) stopped on the cap
    or stalled (Problem.fit's stall), though a later solve of the stage converged (the weak directions grown, the
    fine phase run again): that solve started from where the coarse phase was left, outside the basin (measured:
    sim6_turn at full size with trajectory corrections, its coarse phase capped at J 0.34 cm², then converged fine
    with four upward rings collapsed on the horizon). A fine phase capped and then run again to convergence is
    accepted: it had reached the basin and was still moving."""
    last = history[-1]
    if last.get("stop") != "converged":
        raise CalibrationError(
            f"{where}: the calibration did not converge: it stopped after {len(history)} outer iterations still "
            f"in the {last['phase']} phase (last step {last['max_step']:.2g}); allow more (stopping.max_outer_iterations), "
            "or start from a nominal model closer to the truth")
    stage = _stage(last)
    coarse = [k for k, row in enumerate(history) if _stage(row) == stage and row.get("phase") == "coarse"]
    if coarse and history[coarse[-1]].get("stop") in ("cap", "stalled"):
        row = history[coarse[-1]]
        how = ("stopped on the cap" if row["stop"] == "cap"
               else "stalled (J no longer falling, its step above the fine phase's)")
        raise CalibrationError(
            f"{where}: the calibration did not converge: its coarse phase {how} after outer iteration "
            f"{coarse[-1] + 1} (J {row['energy_after_cm2']:.3g} cm², last step {row['max_step']:.2g}), and the fit "
            "that went on from there started outside the basin; allow more (stopping.max_outer_iterations), or "
            "start from a nominal model, and recorded poses, closer to the truth")


def _stage(row: dict) -> str:
    """The stage (a mode) an outer iteration of the history belongs to: its `mode` without the label of a solve
    made again (", weak directions held")."""
    return str(row.get("mode", "")).split(",")[0]


def check_rings_in_order(elevation_deg: np.ndarray, d_elevation_rad: np.ndarray, prior_sigma_deg: float,
                         where: str) -> None:
    """Raise when two fibres' calibrated elevations cross: a real head's beams keep their order, whenever
    the nominal model's stated uncertainty (prior_sigma_deg, 1-sigma) says its beams are known to within a
    third of their spacing (a start that is further off, Table 4.1's 3 deg on a 1.33 deg spacing, may have
    crossing beams). Crossed rings are either a slide or a nominal model further off than it states (the
    fit then finds the true rings, crossed): the message names both."""
    order = np.argsort(elevation_deg, kind="stable")
    if 3.0 * prior_sigma_deg > np.diff(elevation_deg[order]).min():
        return
    calibrated = (elevation_deg + np.degrees(d_elevation_rad))[order]
    crossed = np.flatnonzero(np.diff(calibrated) <= 0)
    if len(crossed):
        a, b = order[crossed[0]], order[crossed[0] + 1]
        raise CalibrationError(
            f"{where}: the calibrated rings of fibres {a} and {b} cross ({calibrated[crossed[0]]:.3f} and "
            f"{calibrated[crossed[0] + 1]:.3f} deg), which the nominal model's stated uncertainty ({prior_sigma_deg:g} deg) "
            "rules out: if the nominal model is known to be further off, give its uncertainty "
            "(priors.intrinsic_angle_deg); else the elevations slid: hold them (static.hold) or use a drive with "
            "surfaces at many heights")


def outside_priors(estimate, nominal_extrinsic: gtsam.Pose3, layout: Layout,
                   unobservable: list[str]) -> list[tuple[str, float]]:
    """(name, |z|) of each estimated parameter not named unobservable that lies more than PRIOR_SIGMAS of its
    prior sigmas (z) from its nominal value, the furthest first."""
    if not layout.size:
        return []
    whitened = np.linalg.solve(layout.tangent_from_whitened(),
                               tangent_about_nominal(layout, estimate.offsets, estimate.extrinsic, nominal_extrinsic))
    far = [(name, float(abs(z))) for name, z in zip(layout.names, whitened)
           if abs(z) > PRIOR_SIGMAS and name not in unobservable]
    return sorted(far, key=lambda x: -x[1])


def check_within_priors(estimate, nominal_extrinsic: gtsam.Pose3, layout: Layout,
                        unobservable: list[str], where: str) -> None:
    """Raise when an estimated parameter lies outside its priors (outside_priors): the nominal's stated
    uncertainty says it cannot be there."""
    far = outside_priors(estimate, nominal_extrinsic, layout, unobservable)
    if far:
        listed = ", ".join(f"{name} ({z:.0f} sigmas)" for name, z in far[:5])
        raise CalibrationError(
            f"{where}: {len(far)} parameter(s) slid far outside the nominal model's stated uncertainty: {listed}; "
            "if the nominal model is known to be that far off, give its uncertainty (priors.intrinsic_range_m, "
            "priors.intrinsic_angle_deg, priors.extrinsic_*), else hold them (static.hold) or use a drive that shows them")


def check_energy_explained(energy_cm2: float, expected_cm2: float | None, range_noise_m: float, where: str) -> None:
    """Raise when J at the end is ENERGY_EXCESS times above what the pairs' noise model (the measured
    range noise, the trajectory's jitter, the surfaces' departure from planes) predicts; None: no
    prediction (pairs whitened by a nominal sigma0, not by the measured noise)."""
    if expected_cm2 is None or not expected_cm2 > 0:
        return
    if energy_cm2 > ENERGY_EXCESS * expected_cm2:
        raise CalibrationError(
            f"{where}: J ends at {energy_cm2:.3g} cm2 where the measured noise (range {range_noise_m * 1000:.1f} mm) "
            f"predicts {expected_cm2:.3g} cm2: the model leaves something out or the pairs are wrong; run graphcal "
            "diagnose on the recording, or check the trajectory's time stamps and the sensor model")
