"""A calibration run in the viewer: the cloud before and after (coloured by fibre, residual, time),
the trajectory before and after with the control corrections as arrows, J and the weight sum per
outer iteration, the parameters with their 1-sigma, and a blueprint that shows it all at once.

Entity paths (docs/howto/read-the-report-and-viewer.md):
    /summary                                   Markdown: what ran, figures, where things are
    /world                                     RIGHT_HAND_Z_UP, fibre annotation context
    /world/cloud/{before,after}/by_{fibre,time,residual}
    /world/trajectory/{before,after,truth,corrections}
    /metrics/{J_cm2,log10_J_cm2,weight_sum,pairs,max_step}/...   timeline "iteration"
    /parameters/intrinsics/<name>/{estimate,plus_1sigma,minus_1sigma,truth}   timeline "fibre"
    /parameters/corrections/<name>/...         timeline "control"
    /parameters/table                          Markdown table of every estimate and sigma
    /residuals/{before,after}                  histograms of the residuals before and after [cm]
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from graphcal.calibration.before_after import BeforeAfter
from graphcal.calibration.evaluate import (
    Evaluation,
    nominal_calibration,
    returns_for,
    world_of,
)
from graphcal.calibration.observability import intrinsic_mask
from graphcal.calibration.result import CalibrationResult
from graphcal.recording.geodesy import to_world
from graphcal.recording.intrinsics import (
    DISPLAY_FROM_FILE_UNITS,
    DISPLAY_NAMES,
    offsets_to_file_units,
)
from graphcal.recording.directory import Recording
from graphcal.viewer.colors import fibre_annotations
from graphcal.viewer.log import (
    VIEWER_POINTS,
    collapsed_panels,
    eye_over,
    log_arrows,
    log_cloud,
    log_histogram,
    log_line,
    log_series,
    log_summary,
    log_with_sigma,
)
from graphcal.viewer.stream import send_layout

ARROW_SCALE = 10.0  # trajectory corrections are centimetres on a 100 m scene: drawn 10x longer
MAX_TRAJECTORY_POINTS = 20_000
BEFORE, AFTER, TRUTH = (160, 160, 160), (40, 200, 90), (240, 160, 30)
COLOURINGS = ("residual", "fibre", "time")  # the first tab is the one shown


@dataclass(frozen=True)
class Shown:
    """What the viewer holds, for the summary: returns shown, the local origin [m, world CRS]."""

    returns: int
    origin_m: np.ndarray
    residual_scale_m: float


def log_calibration(stream: rr.RecordingStream, recording: Recording, result: CalibrationResult,
                    residuals: BeforeAfter, evaluation: Evaluation | None = None, folder: Path | None = None,
                    max_points: int = VIEWER_POINTS, seed: int = 0) -> None:
    """Everything about one calibration run (module docstring), and its blueprint's data."""
    calibration = result.calibration
    data = returns_for(calibration, recording, max_points, seed)
    origin = data.origin_m
    clouds = {"before": world_of(nominal_calibration(recording), data) - origin,
              "after": world_of(calibration, data) - origin}
    send_layout(stream, calibration_blueprint(result.estimated, eye_over(clouds["after"])))
    stream.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    stream.log("world", fibre_annotations(recording.sensor.elevation_deg), static=True)
    span = (float(data.time_s.min()), float(data.time_s.max()))
    scale = float(np.percentile(np.abs(residuals.before.residual_m), 95)) if len(residuals.before.row_p) else 0.01
    rng = np.random.default_rng(seed)
    for name, pairs in (("before", residuals.before), ("after", residuals.after)):
        log_cloud(stream, f"world/cloud/{name}", clouds[name], fibre=data.fibre, time_s=(data.time_s, *span))
        shown = np.sort(rng.choice(len(pairs.row_p), min(len(pairs.row_p), max_points), replace=False))
        log_cloud(stream, f"world/cloud/{name}", pairs.p_m[shown] - origin,
                  residual_m=(pairs.residual_m[shown], scale))
    log_trajectories(stream, recording, result, origin)
    log_history(stream, result.history)
    log_parameters(stream, recording, result)
    edges = np.linspace(-3 * scale, 3 * scale, 61) * 100.0
    log_histogram(stream, "residuals/before", residuals.before.residual_m * 100.0, edges, BEFORE)
    log_histogram(stream, "residuals/after", residuals.after.residual_m * 100.0, edges, AFTER)
    log_summary(stream, calibration_summary(recording, result, residuals, evaluation, folder,
                                            Shown(len(data.rows), origin, scale)))


def log_trajectories(stream: rr.RecordingStream, recording: Recording, result: CalibrationResult,
                     origin_m: np.ndarray) -> None:
    """The INS trajectory (before), corrected by the control corrections (after), the truth when
    known, and each control's translation correction as an arrow (ARROW_SCALE x its length)."""
    poses = recording.world.poses
    step = max(1, len(poses.time) // MAX_TRAJECTORY_POINTS)
    time, before = poses.time[::step], poses.position_m[::step]
    log_line(stream, "world/trajectory/before", before - origin_m, BEFORE, "INS trajectory (before)")
    truth = recording.truth
    if truth is not None:
        true_poses = to_world(truth.trajectory, recording.crs).poses
        log_line(stream, "world/trajectory/truth", true_poses.position_m[::step] - origin_m, TRUTH, "true trajectory")
    if not result.estimated[2]:
        return
    control_times = result.calibration.control_times_s
    shift = np.array([c.translation() for c in result.calibration.estimate.corrections])
    after = before + np.column_stack([np.interp(time, control_times, shift[:, k]) for k in range(3)])
    log_line(stream, "world/trajectory/after", after - origin_m, AFTER, "corrected trajectory (after)")
    inside = (control_times >= poses.span[0]) & (control_times <= poses.span[1])
    at, _ = poses.interpolate(control_times[inside])
    labels = [f"control {c}: {np.linalg.norm(v) * 100:.1f} cm" for c, v in zip(np.flatnonzero(inside), shift[inside])]
    log_arrows(stream, "world/trajectory/corrections", at - origin_m, ARROW_SCALE * shift[inside], AFTER, labels)


def log_history(stream: rr.RecordingStream, history: list[dict]) -> None:
    """Per outer iteration (timeline "iteration"): J before and after its solve [cm^2] (and their
    log10, J falls by orders of magnitude), the weight sum, the pairs, the largest step."""
    iteration = np.arange(len(history))
    column = {key: np.array([row[key] for row in history], dtype=np.float64)
              for key in ("energy_cm2", "energy_after_cm2", "weight_sum", "pairs", "max_step")}
    for name, transform in (("J_cm2", lambda v: v), ("log10_J_cm2", np.log10)):
        log_series(stream, f"metrics/{name}/before_solve", "iteration", iteration,
                   transform(column["energy_cm2"]), "J before the solve", (220, 80, 60))
        log_series(stream, f"metrics/{name}/after_solve", "iteration", iteration,
                   transform(column["energy_after_cm2"]), "J after the solve", (40, 160, 80))
    log_series(stream, "metrics/weight_sum", "iteration", iteration, column["weight_sum"], "weight sum",
               (90, 120, 220))
    log_series(stream, "metrics/pairs", "iteration", iteration, column["pairs"], "pairs", (140, 90, 200))
    log_series(stream, "metrics/max_step", "iteration", iteration, column["max_step"], "max |dX| [m or rad]",
               (120, 120, 120))


def log_parameters(stream: rr.RecordingStream, recording: Recording, result: CalibrationResult) -> None:
    """Per-fibre intrinsics (timeline "fibre") and per-control corrections (timeline "control")
    with 1-sigma bands and truth when known; a Markdown table of every estimate."""
    calibration, uncertainty = result.calibration, result.sigmas
    truth = recording.truth
    if result.estimated[0]:
        values = offsets_to_file_units(calibration.estimate.offsets)
        true = offsets_to_file_units(truth.intrinsics) if truth is not None else None
        held = intrinsic_mask(calibration.unobservable, values.shape[0])
        for k, (name, factor) in enumerate(zip(DISPLAY_NAMES, DISPLAY_FROM_FILE_UNITS)):
            log_with_sigma(stream, f"parameters/intrinsics/{name}", "fibre",
                           np.where(held[:, k], np.nan, values[:, k] * factor), uncertainty.intrinsics[:, k] * factor,
                           None if true is None else true[:, k] * factor)
    if result.estimated[2]:
        corrections = calibration.estimate.corrections
        translation_cm = np.array([c.translation() for c in corrections]) * 100.0
        for k, name in enumerate(("x_cm", "y_cm", "z_cm")):
            log_with_sigma(stream, f"parameters/corrections/{name}", "control", translation_cm[:, k],
                           uncertainty.controls[:, 3 + k] * 100.0)
    log_summary(stream, parameter_table(result), "parameters/table")


def parameter_table(result: CalibrationResult) -> str:
    """Markdown tables: extrinsic, intrinsics per fibre, corrections per control, estimate ± 1-sigma
    (file units), 'unobservable' where held at nominal."""
    from graphcal.report.tables import parameter_rows

    lines = []
    for title, header, rows in parameter_rows(result.to_yaml_dict("graphcal")):
        lines += [f"### {title}", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        lines += ["| " + " | ".join(row) + " |" for row in rows] + [""]
    return "\n".join(lines)


def calibration_summary(recording: Recording, result: CalibrationResult, residuals: BeforeAfter,
                        evaluation: Evaluation | None, folder: Path | None, shown: Shown) -> str:
    before, after = result.energy_cm2
    used = result.config.max_points or len(recording.points)
    lines = [f"# graphcal calibrate: {recording.name}", "",
             (f"mode **{result.config.mode}**, {min(used, len(recording.points)):,} of {len(recording.points):,} "
             f"returns used, {len(result.history)} outer iterations, {result.seconds:.1f} s"), "",
             f"- J (history): {before:.3g} cm² before the first solve, {after:.3g} cm² after the last",
             (f"- the returns paired as the first iteration pairs them: J {residuals.before.energy_cm2():.3g} cm² "
              f"in the nominal cloud ({len(residuals.before.row_p):,} pairs), {residuals.after.energy_cm2():.3g} cm² "
              f"in the calibrated one ({len(residuals.after.row_p):,} pairs)"),
             f"- unobservable (held at nominal or bound by the prior): {', '.join(result.unobservable) or 'none'}",
             f"- imprecise (fitted, 1-sigma above the accuracy required): "
             f"{', '.join(result.calibration.imprecise) or 'none'}"]
    if evaluation is not None:
        lines.append(f"- {evaluation.cloud_line()}")
    lines += ["", "## Reading the views",
              ("- top: the cloud before (left) and after (right); tabs colour it by **residual**, by **fibre** "
              "(hover a point for its fibre) or by **time**"),
              (f"- residual colours: signed point-to-plane residual n·(p−m) of each pair in that cloud, "
              f"blue −{shown.residual_scale_m * 100:.2g} cm .. red +{shown.residual_scale_m * 100:.2g} cm, the same "
              f"scale before and after; only the paired returns p are drawn (at most {shown.returns:,})"),
              ("- trajectory: INS (grey, before), corrected (green, after), truth (orange, when known); green arrows: "
              f"the translation correction at each control time, drawn {ARROW_SCALE:g}x longer"),
              ("- bottom: J and the weight sum per outer iteration (timeline `iteration`); per-fibre intrinsics and "
              "per-control corrections with their 1-sigma band: select the timeline `fibre` or `control` in the "
              "time panel; every number is in the parameters table tab"),
              "", "## Data",
              f"- {shown.returns:,} random returns drawn per cloud (of {len(recording.points):,})",
              (f"- positions relative to the local origin E {shown.origin_m[0]:.0f} m, N {shown.origin_m[1]:.0f} m, "
              f"up {shown.origin_m[2]:.0f} m in {recording.world.crs.to_string()} (rerun stores float32)")]
    if folder is not None:
        lines.append(f"- run folder: `{folder}` (calibration.yaml, report.html, ...)")
    return "\n".join(lines)


def calibration_blueprint(estimated: tuple[bool, bool, bool], eye: rrb.EyeControls3D) -> rrb.Blueprint:
    """Before | after clouds on top (tabs per colouring, the same starting camera), summary, J and
    weight sum, parameters below; side panels collapsed."""
    def clouds(which: str, trajectories: list[str]) -> rrb.Tabs:
        return rrb.Tabs(*[rrb.Spatial3DView(name=f"{which}: colour by {colouring}", origin="/world",
                                            contents=[f"+ /world/cloud/{which}/by_{colouring}"]
                                            + [f"+ /world/trajectory/{t}" for t in trajectories],
                                            eye_controls=eye)
                          for colouring in COLOURINGS])

    parameters = [rrb.TextDocumentView(origin="/parameters/table", name="parameters table"),
                  rrb.BarChartView(origin="/residuals/before", name="residuals before [cm]"),
                  rrb.BarChartView(origin="/residuals/after", name="residuals after [cm]")]
    if estimated[0]:
        parameters += [rrb.TimeSeriesView(origin=f"/parameters/intrinsics/{name}", name=f"{name} per fibre")
                       for name in DISPLAY_NAMES]
    if estimated[2]:
        parameters += [rrb.TimeSeriesView(origin=f"/parameters/corrections/{name}", name=f"correction {name}")
                       for name in ("x_cm", "y_cm", "z_cm")]
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(clouds("before", ["before", "truth"]), clouds("after", ["after", "corrections", "truth"])),
            rrb.Horizontal(
                rrb.TextDocumentView(origin="/summary", name="summary"),
                rrb.Vertical(rrb.TimeSeriesView(origin="/metrics/log10_J_cm2", name="log10 J [cm²] per iteration"),
                             rrb.TimeSeriesView(origin="/metrics/weight_sum", name="weight sum per iteration")),
                rrb.Tabs(*parameters),
                column_shares=[2, 2, 3]),
            row_shares=[3, 2]),
        *collapsed_panels("iteration"))

