"""A diagnosis in the viewer: the final fit's residual field, coloured by the residual and by each
regressor the mismatch finder bins it against, the binned effects, and the findings.

Entity paths (docs/howto/read-the-report-and-viewer.md):
    /summary                              Markdown: findings, J before -> after, how to read the views
    /world                                RIGHT_HAND_Z_UP
    /world/residual/by_residual           the paired returns p, oriented residual, blue -3 cm .. red +3 cm
    /world/residual/by_<regressor>        the same points coloured by a regressor (viridis, 1st-99th percentile)
    /binned/<regressor>                   trimmed-mean residual less the field's [cm] per bin, timeline "bin"
    /discovered/<channel>_by_<regressor>  a discovered finding's curve (estimate) and its 1-sigma band, in the
                                          finding's unit, over its grid of the regressor (timeline "curve_point";
                                          the summary gives the regressor's range)
A comparison with a simulation has no fit of its own: the file holds the summary only.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb
from scipy import stats

from graphcal.diagnosis.diagnose import Diagnosis
from graphcal.diagnosis.locate import (
    bins,
    centred_residual_cm,
    oriented_residual_m,
    regressors,
)
from graphcal.recording.directory import Recording
from graphcal.viewer.log import (
    VIEWER_POINTS,
    collapsed_panels,
    eye_over,
    log_cloud,
    log_coloured,
    log_series,
    log_summary,
    log_with_sigma,
)
from graphcal.viewer.stream import send_layout

RESIDUAL_SCALE_M = 0.03
BINNED = (30, 110, 220)


def log_diagnosis(stream: rr.RecordingStream, recording: Recording, diagnosis: Diagnosis, folder: Path | None = None,
                  max_points: int = VIEWER_POINTS, seed: int = 0) -> None:
    """Everything about one diagnosis (module docstring) and its blueprint."""
    fit = diagnosis.fit
    if fit is None:
        send_layout(stream, rrb.Blueprint(rrb.TextDocumentView(origin="/summary", name="summary"),
                                          *collapsed_panels("bin")))
        log_summary(stream, diagnosis_summary(recording, diagnosis, folder, 0, None))
        return
    p = fit.pairs.index_p
    shown = np.sort(np.random.default_rng(seed).choice(len(p), min(len(p), max_points), replace=False))
    xyz = fit.points_m[p[shown]]
    values = regressors(fit)
    discovered = [f for f in diagnosis.findings if f["effect"] == "discovered"]
    send_layout(stream, diagnosis_blueprint(list(values), eye_over(xyz), [discovered_path(f) for f in discovered]))
    stream.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    log_cloud(stream, "world/residual", xyz, residual_m=(oriented_residual_m(fit)[shown], RESIDUAL_SCALE_M))
    residual_cm = centred_residual_cm(fit)
    for name, value in values.items():
        low, high = np.quantile(value, [0.01, 0.99])
        log_coloured(stream, f"world/residual/by_{name}", xyz, value[shown], low, high)
        edges, index = bins(value, name)
        effect_cm = np.array([stats.trim_mean(residual_cm[index == b], 0.1) if np.any(index == b) else np.nan
                              for b in range(len(edges) - 1)])
        log_series(stream, f"binned/{name}", "bin", np.arange(len(effect_cm)), effect_cm, name, BINNED, points=True)
    for finding in discovered:
        curve = finding["curve"]
        log_with_sigma(stream, discovered_path(finding), "curve_point", np.asarray(curve["y"], dtype=np.float64),
                       np.asarray(curve["sigma"], dtype=np.float64))
    log_summary(stream, diagnosis_summary(recording, diagnosis, folder, len(shown), fit.data.origin_m))


def diagnosis_summary(recording: Recording, diagnosis: Diagnosis, folder: Path | None, shown: int,
                      origin_m: np.ndarray | None) -> str:
    energy = diagnosis.energy_cm2
    lines = [f"# graphcal diagnose: {recording.name}", "", f"{diagnosis.seconds:.1f} s", "", "## Findings", ""]
    lines += [f"- {f['statement']}" for f in diagnosis.findings] or [f"- {diagnosis.summary()}"]
    if diagnosis.findings and diagnosis.slid_statement:
        lines.append(f"- {diagnosis.slid_statement}")
    lines += [f"- not separable: {', '.join(row['effects'])} (correlation {row['correlation']:.2f}, named "
              f"{row['named']}); {row['would_separate']}" for row in diagnosis.not_separable]
    if "after" in energy:
        lines.append(f"- J {energy['before']:.3g} cm² with the nominal model, {energy['after']:.3g} cm² with the "
                     "effects modelled")
    if origin_m is not None:
        lines += ["", "## Reading the views",
                  (f"- top: the returns p of the final fit's pairs ({shown:,} drawn), tabs colour them by their "
                   f"residual (along the beam: red behind the surface, blue in front, ±{RESIDUAL_SCALE_M * 100:g} cm) "
                   "or by each regressor of the located structure"),
                  ("- bottom: per bin of each regressor (quantile bins, one per fibre), the trimmed-mean residual "
                   "less the whole field's [cm]: a flat line is no structure; select the timeline `bin`"),
                  *[(f"- discovered/{f['channel']}_by_{f['regressor']}: the {f['channel']} error ({f['unit']}) with "
                     f"its 1-sigma band over {len(f['curve']['x'])} points of the {f['regressor']} from "
                     f"{f['curve']['x'][0]:.4g} to {f['curve']['x'][-1]:.4g}; select the timeline `curve_point`")
                    for f in diagnosis.findings if f["effect"] == "discovered"],
                  "", "## Data",
                  (f"- positions relative to the local origin E {origin_m[0]:.0f} m, N {origin_m[1]:.0f} m, "
                   f"up {origin_m[2]:.0f} m in {recording.world.crs.to_string()} (rerun stores float32)")]
    if folder is not None:
        lines.append(f"- run folder: `{folder}` (diagnosis.json, calibration/ ...)")
    return "\n".join(lines)


def discovered_path(finding: dict) -> str:
    """The entity of a discovered finding's curve."""
    return f"discovered/{finding['channel']}_by_{finding['regressor']}"


def diagnosis_blueprint(regressor_names: list[str], eye: rrb.EyeControls3D,
                        discovered: list[str] = ()) -> rrb.Blueprint:
    """The residual field on top (tabs per colouring, the residual first), summary and the binned
    effects and discovered curves below; side panels collapsed."""
    colourings = ["residual"] + regressor_names
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Tabs(*[rrb.Spatial3DView(name=f"colour by {colouring}", origin="/world",
                                         contents=[f"+ /world/residual/by_{colouring}"], eye_controls=eye)
                       for colouring in colourings]),
            rrb.Horizontal(
                rrb.TextDocumentView(origin="/summary", name="summary"),
                rrb.Tabs(*[rrb.TimeSeriesView(origin=f"/{path}", name=path.replace("/", ": "))
                           for path in discovered],
                         *[rrb.TimeSeriesView(origin=f"/binned/{name}", name=f"residual per {name} bin [cm]")
                           for name in regressor_names]),
                column_shares=[2, 3]),
            row_shares=[3, 2]),
        *collapsed_panels("bin"))
