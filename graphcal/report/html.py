"""report.html of a calibration run folder: one self-contained file (figures as base64 PNG).

It is built from the folder's files alone (calibration.yaml, history.csv, pairs_nominal.parquet and
pairs_calibrated.parquet, evaluation.yaml, run.yaml), plus the recording's truth/ when run.yaml names a recording that has
one (true offsets and INS errors drawn next to the estimates)."""

from __future__ import annotations

import base64
import csv
import html
from pathlib import Path

import numpy as np

from graphcal.common.atomic import atomic_path
from graphcal.calibration.before_after import FILES as PAIRS_FILES
from graphcal.calibration.before_after import BeforeAfter
from graphcal.calibration.result import (
    CALIBRATION_FILE,
    HALVES_FILE,
    read_calibration_yaml,
)
from graphcal.common.errors import RecordingError
from graphcal.report import figures
from graphcal.report.tables import (
    INTRINSIC_COLUMNS,
    intrinsics_estimated,
    parameter_rows,
)
from graphcal.common.run_folder import MANIFEST
from graphcal.common.yamlfile import read_yaml

REPORT = "report.html"
EVALUATION = "evaluation.yaml"
HISTORY_COLUMNS = ("mode", "energy_cm2", "energy_after_cm2", "weight_sum")  # the history.csv columns it draws
_STYLE = """body{font-family:system-ui,sans-serif;max-width:1150px;margin:2em auto;color:#222;line-height:1.4}
h1{font-size:1.6em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:1.6em}
table{border-collapse:collapse;margin:.6em 0;font-size:.9em}td,th{border:1px solid #ccc;padding:.2em .6em;text-align:right}
th{background:#f2f2f2}td:first-child{text-align:left}img{max-width:100%}pre{background:#f6f6f6;padding:.6em}
.unobservable{color:#888;font-style:italic}.note{color:#555;font-size:.92em}"""


def write_report(folder: Path, named_as: Path | None = None) -> Path:
    """Write folder/report.html from the run folder's files; returns its path. named_as: the folder the page
    names (a run's final place while the run is written in a working folder; None: folder)."""
    folder = Path(folder)
    named_as = folder if named_as is None else Path(named_as)
    calibration_path = folder / CALIBRATION_FILE
    if not calibration_path.is_file():
        raise RecordingError(folder, "no calibration.yaml", expected="a calibration run folder (graphcal calibrate)")
    calibration = read_calibration_yaml(calibration_path)
    manifest = read_yaml(folder / MANIFEST) if (folder / MANIFEST).is_file() else {}
    history = _read_history(folder / "history.csv")
    recording = _recording(manifest)
    sections = [_header(named_as, calibration, manifest, history),
                section("Energy J per outer iteration", image(figures.energy_png(history)),
                         "J = Σ w (n·(p−m))² / Σ w over the pairs of each outer iteration (eq. 4.4); it is not "
                         "monotonic when the pairs change (the gate opens, the fine phase starts)."),
                _residuals(folder), _truth(folder), _parameters(calibration, recording), _halves(folder),
                _timings(manifest)]
    return write_page(folder, "graphcal report", sections, named_as)


def write_page(folder: Path, title: str, sections: list[str], named_as: Path) -> Path:
    """folder/report.html, atomically: one self-contained page of the sections' HTML, titled title: the name of
    named_as (write_report)."""
    page = (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}: "
            f"{html.escape(named_as.name)}</title><style>{_STYLE}</style></head><body>{''.join(sections)}</body></html>")
    with atomic_path(folder / REPORT) as tmp:
        tmp.write_text(page, encoding="utf-8")
    return folder / REPORT


def _read_history(path: Path) -> list[dict]:
    if not path.is_file():
        raise RecordingError(path, "file not found", expected="the history graphcal calibrate writes")
    with path.open(newline="") as stream:
        reader = csv.DictReader(stream)
        missing = [name for name in HISTORY_COLUMNS if name not in (reader.fieldnames or [])]
        if missing:
            raise RecordingError(path, f"no column {', '.join(missing)}", field=missing[0],
                                 expected=f"the columns graphcal calibrate writes ({', '.join(HISTORY_COLUMNS)})")
        return list(reader)


def _recording(manifest: dict):
    """The run's recording when run.yaml names one that is still there, else None."""
    from graphcal.recording.directory import Recording

    path = manifest.get("recording")
    if not path or not Path(path, "recording.yaml").is_file():
        return None
    return Recording.load(path, validate=False)


def image(png: bytes, alt: str = "figure") -> str:
    return f"<img alt='{alt}' src='data:image/png;base64,{base64.b64encode(png).decode('ascii')}'>"


def section(title: str, body: str, note: str = "") -> str:
    return f"<h2>{html.escape(title)}</h2>" + (f"<p class='note'>{html.escape(note)}</p>" if note else "") + body


def table(header: list[str], rows: list[list[str]]) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td class='unobservable'>{html.escape(c)}</td>" if c == "unobservable"
                                    else f"<td>{html.escape(c)}</td>" for c in row) + "</tr>" for row in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def _header(folder: Path, calibration: dict, manifest: dict, history: list[dict]) -> str:
    energy = calibration.get("energy_cm2", {})
    provenance = calibration.get("provenance", {})
    rows = [["run folder", str(folder)], ["recording", str(manifest.get("recording", "not recorded"))],
            ["command", " ".join(manifest.get("argv", [])) or provenance.get("command", "")],
            ["created (UTC)", str(manifest.get("created", provenance.get("created", "")))],
            ["graphcal / gtsam", f"{provenance.get('graphcal', '?')} / {provenance.get('gtsam', '?')}"],
            ["sensor", f"{calibration['sensor']['model']}, reference fibre {calibration['sensor']['reference_fibre']}"],
            ["stages", ", ".join(dict.fromkeys(row["mode"] for row in history))],
            ["outer iterations", str(len(history))],
            ["J before → after [cm²]", f"{energy.get('before', float('nan')):.4g} → {energy.get('after', float('nan')):.4g}"],
            ["steps of the recorded positions", steps_line(calibration.get("ins_steps_s") or [])],
            ["what the drive could not observe",
             calibration.get("verdict") or "nothing beyond the drive's common motion"],
            ["unobservable", ", ".join(calibration.get("unobservable") or []) or "none"],
            ["imprecise (fitted, 1-sigma above the accuracy required)",
             ", ".join(calibration.get("imprecise") or {}) or "none"]]
    return f"<h1>graphcal calibration report: {html.escape(folder.name)}</h1>" + table(["", ""], rows)


def steps_line(steps_s) -> str:
    """The INS's steps ((S, 2) times [s], calibration.yaml's ins_steps_s) in one line: none, or how many and when."""
    if len(steps_s) == 0:
        return "none"
    times = ", ".join(f"{before:.2f}" for before, _ in steps_s[:10]) + (", ..." if len(steps_s) > 10 else "")
    return f"{len(steps_s)} (a GNSS update's jump), at t = {times} s: a trajectory control on each side of each"


def _residuals(folder: Path) -> str:
    if not all((folder / name).is_file() for name in PAIRS_FILES.values()):
        return section("Residuals before and after", "<p>not computed for this run (no pairs_*.parquet)</p>")
    residuals = BeforeAfter.load(folder)
    before, after = residuals.before, residuals.after
    settings = read_yaml(folder / "config.yaml") if (folder / "config.yaml").is_file() else {}
    how = ("strict settings: the calibration's pairs were made once, in the nominal cloud, so before are exactly "
           "its pairs" if settings.get("fixed_association") else
           "coarse settings: nothing cut on the distance to the plane, so some pairs across edges remain even in a "
           "perfect cloud")
    counts = (f"Before: {len(before.row_p):,} pairs, J {before.energy_cm2():.4g} cm²; after: {len(after.row_p):,} "
              f"pairs, J {after.energy_cm2():.4g} cm².")
    return (section("Residuals before and after", image(figures.residuals_png(before.residual_m, after.residual_m)),
                     "Signed point-to-plane residuals of the returns the calibration used, paired in the nominal "
                     "cloud (before) and again in the calibrated cloud (after) as the first outer iteration pairs "
                     f"them ({how}). {counts}")
            + section("The cloud before and after",
                       image(figures.cloud_png(before.p_m, before.residual_m, after.p_m, after.residual_m),
                              "cloud before and after"),
                       "The paired returns of each cloud coloured by their residual, on one colour scale. " + counts))


def _truth(folder: Path) -> str:
    if not (folder / EVALUATION).is_file():
        return section("Errors against truth", "<p>no truth for this recording (real data), or not evaluated: "
                                                "<code>graphcal evaluate RUN_DIR RECORDING</code></p>")
    evaluation = read_yaml(folder / EVALUATION)
    return section("Errors against truth", f"<pre>{html.escape(evaluation['table'])}</pre>",
                    "Intrinsics: RMS over the fibres but the reference of (estimate − truth), eq. 4.6. c2c: distance "
                    "from each calibrated return to the nearest true return; c2c mean* once the rigid motion that "
                    "no self-calibration observes (the trajectory's common translation/rotation) is removed.")


def _parameters(calibration: dict, recording) -> str:
    truth = recording.truth if recording is not None else None
    parts = []
    if intrinsics_estimated(calibration):
        parts.append(image(_intrinsics_figure(calibration, truth)))
    corrections = calibration.get("trajectory_corrections") or []
    if corrections:
        parts.append(image(_corrections_figure(corrections, recording)))
    for title, header, rows in parameter_rows(calibration):
        parts.append(f"<h3>{html.escape(title)}</h3>" + table(header, rows))
    return section("Parameters with 1-sigma", "".join(parts),
                    "1-sigma from the marginal covariances of the final graph (σ0 the nominal point noise). "
                    "'(unobservable)': the data see it, alone or in combination with others, less than ten times "
                    "better than the nominal model's stated uncertainty; it is kept at its nominal value along what "
                    "the data do not see, its sigma is the prior's, and it is not a measurement (calibration.yaml "
                    "says why in unobservable_reasons). '(imprecise)': the data determine it, to a 1-sigma above the "
                    "accuracy required (settings accuracy); its fitted value is kept and exported. 'held at "
                    "nominal': held by a setting or a static sensor's checks.")


def _intrinsics_figure(calibration: dict, truth) -> bytes:
    from graphcal.recording.intrinsics import offsets_to_file_units

    rows = calibration["intrinsics"]
    keys = [key for key, _, _ in INTRINSIC_COLUMNS]
    factor = np.array([f for _, _, f in INTRINSIC_COLUMNS])
    values = np.array([[np.nan if row[k] is None else row[k] for k in keys] for row in rows]) * factor
    sigma = np.array([[np.nan if not row.get("sigma") or row["sigma"][k] is None else row["sigma"][k] for k in keys]
                      for row in rows]) * factor
    true = offsets_to_file_units(truth.intrinsics) * factor if truth is not None else None
    return figures.intrinsics_png(values, sigma, true, np.isnan(values), [name for _, name, _ in INTRINSIC_COLUMNS],
                                  calibration["sensor"]["reference_fibre"])


def _corrections_figure(corrections: list[dict], recording) -> bytes:
    time = np.array([row["time"] for row in corrections])
    values = np.array([row["d_position_m"] for row in corrections]) * 100.0
    sigma = np.array([[np.nan if row["sigma"][f"{a}_m"] is None else row["sigma"][f"{a}_m"] for a in "xyz"]
                      for row in corrections]) * 100.0
    truth = None
    if recording is not None and recording.truth is not None:
        from graphcal.recording.geodesy import to_world

        recorded, true = recording.world.poses, to_world(recording.truth.trajectory, recording.crs).poses
        inside = (time >= max(recorded.span[0], true.span[0])) & (time <= min(recorded.span[1], true.span[1]))
        truth = np.full_like(values, np.nan)
        truth[inside] = (true.interpolate(time[inside])[0] - recorded.interpolate(time[inside])[0]) * 100.0
    return figures.corrections_png(time, values, sigma, truth)


def _halves(folder: Path) -> str:
    """A static sensor's azimuth-halves check (halves.yaml), when the run made one."""
    if not (folder / HALVES_FILE).is_file():
        return ""
    check = read_yaml(folder / HALVES_FILE)
    factor = {key: f for key, _, f in INTRINSIC_COLUMNS}
    names = sorted({name for fold in check["folds"] for name in fold["estimates"]},
                   key=lambda name: (int(name.split(".")[0].split("_")[1]), name))  # fibre_<n>.<parameter>
    header = ["fitted on", "J own pairs [cm²]", "J other half (held out) [cm²]"] + [
        f"{name} [{'deg' if name.endswith('_deg') else 'cm'}]" for name in names]
    rows = [[fold["fitted_on"],
             f"{fold['energy_cm2']['before']:.4g} → {fold['energy_cm2']['after']:.4g}",
             f"{fold['held_out_energy_cm2']['before']:.4g} → {fold['held_out_energy_cm2']['after']:.4g}"]
            + [f"{fold['estimates'][name] * factor[name.split('.')[1]]:.3g}" for name in names]
            for fold in check["folds"]]
    verdict = ("passed: each half's fit lowered J on the other half's pairs, so the estimates are kept" if
               check["passed"] else "failed: a half's fit raised J on the other half's pairs, so what it estimated "
               "fits the surfaces that half sees, not the sensor; every intrinsic left is held at nominal and named "
               "unobservable")
    return section("What this static recording determines: the azimuth-halves check", table(header, rows),
                    "A static head sees each surface from one viewpoint, so an offset can fit the shape of the "
                    "surfaces between its rings as well as the sensor. The intrinsics left after the soft ones are "
                    "held were fitted on the pairs of each azimuth half of the scene; those one half alone does not "
                    "determine and those the halves disagreed on were held, and each half's fit of the rest was tried "
                    f"on the other half's pairs ({len(check['held'])} held by this check in all). Verdict: {verdict}. "
                    "The estimates in the table are each half's fit, not the calibration (docs/reference/math.md "
                    "\"A static sensor\").")


def _timings(manifest: dict) -> str:
    timings = manifest.get("timings_s") or {}
    if not timings:
        return section("Time per stage", "<p>not recorded (no run.yaml)</p>")
    rows = [[name, f"{seconds:.2f}"] for name, seconds in timings.items()]
    return section("Time per stage", image(figures.timings_png(timings)) + table(["stage", "seconds"], rows),
                    "Wall-clock seconds of each stage of the run (the report itself is timed after it is written).")
