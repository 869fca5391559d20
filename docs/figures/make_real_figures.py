"""Figures of docs/howto/real-recordings.md from `graphcal diagnose --open-world` run folders.

For each run folder (default: every folder under /tmp/real_runs) it writes into docs/figures/real/:

- <run>_binned.png: the residual field of the nominal-model fit (the diagnosis's baseline: what
  `locations_baseline` of diagnosis.json is computed on) binned against each regressor that varies,
  exactly as the diagnosis bins it (graphcal.diagnosis.locate: oriented point-to-plane residual less its
  trimmed mean, trimmed mean per quantile bin, one bin per fibre), with +-2 standard errors of the
  cluster means (0.5 s x 4 m clusters). Red points are the bins diagnosis.json reports (q < 0.001,
  |effect| >= 1 mm). The baseline fit is recomputed from the recording named in run.yaml with the
  settings diagnose used (its --mode and --config, else diagnose's default subset of the returns; uniform
  pair noise, seed 0): a calibration, so it takes about as long as the first stage of the diagnosis.
- <run>_discovered.png when the run discovered effects: each discovered curve with its 1-sigma band and
  the residuals binned against its regressor before and after it was modelled, from diagnosis.json alone;
- <run>_tests.png otherwise: each candidate's first-round score statistic per degree of freedom, coloured
  by the verdict (significant and plausible, significant but beyond its physical size, not significant,
  not observable), from diagnosis.json alone.

With --motion RECORDING it also writes <recording folder name>_motion.png, a check of the static
assumption that uses no graphcal code: each full revolution registered (open3d ICP, point to plane,
0.3 m gate) onto the first five, with the nominal catalogue model (x = r cos e cos a, y = -r cos e sin a,
z = r sin e); a head at rest gives zero translation and yaw; and the share of returns whose range
differs by more than 20 cm from the first five revolutions' (per fibre, at the same azimuth).

    .venv/bin/python docs/figures/make_real_figures.py [RUN_FOLDER ...] [--no-binned] [--motion RECORDING]

Matplotlib (Agg), deterministic for fixed run folders.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import yaml  # noqa: E402
from scipy import stats  # noqa: E402

OUT = Path(__file__).resolve().parent / "real"
RUNS = Path("/tmp/real_runs")
UNITS = {"fibre": "fibre (firing order)", "azimuth_deg": "encoder azimuth [deg]",
         "sweep_fraction": "fraction of the revolution", "time_s": "time since the first pose [s]",
         "range_m": "range [m]", "incidence_deg": "incidence [deg]", "intensity": "intensity"}
CURVE_AXES = {"time": "time since the first pose [s]", "incidence": "incidence [deg]", "range": "range [m]",
              "azimuth": "azimuth [deg]", "intensity": "intensity", "fibre": "fibre", "speed": "speed [m/s]",
              "yaw_rate": "yaw rate [deg/s]"}
ALPHA = 1e-3  # the diagnosis's level, Bonferroni over every candidate
DPI = 90


def binned_figure(run: Path, diagnosis: dict, out: Path) -> None:
    """The baseline fit's residuals binned against each varying regressor (module docstring)."""
    import graphcal
    from graphcal.diagnosis.fit import baseline
    from graphcal.diagnosis.locate import bins, centred_residual_cm, regressors

    run_yaml = yaml.safe_load((run / "run.yaml").read_text())
    recording = graphcal.Recording.load(run_yaml["recording"])
    argv = run_yaml.get("argv", [])
    if "--config" in argv:
        settings = yaml.safe_load(Path(argv[argv.index("--config") + 1]).read_text()) or {}
    else:  # diagnose's own default: a seeded subset of its returns
        import importlib

        limit = getattr(importlib.import_module("graphcal.diagnosis.diagnose"), "DIAGNOSE_MAX_POINTS", None)
        settings = {"max_points": limit} if limit else {}
    mode = argv[argv.index("--mode") + 1] if "--mode" in argv else "joint"
    config = graphcal.CalibrationConfig(mode=mode, **settings).with_settings(weighting={"pair_noise": "uniform"})
    fit, _ = baseline(recording, config)
    residual = centred_residual_cm(fit)
    cluster, _ = fit.clusters()
    values = {name: v for name, v in regressors(fit).items() if name in UNITS and np.ptp(v) > 0}
    reported = {(row["regressor"], round(row["bin"][0], 6)) for row in diagnosis["locations_baseline"] if "bin" in row}
    columns = 4
    rows = math.ceil((len(values) + 1) / columns)
    figure, axes = plt.subplots(rows, columns, figsize=(12, 2.9 * rows), squeeze=False)
    for ax, (name, value) in zip(axes.flat, values.items()):
        edges, index = bins(value, name)
        centre, mean, error, flagged = [], [], [], []
        for b in range(len(edges) - 1):
            inside = index == b
            if not np.any(inside):
                continue
            groups = np.unique(cluster[inside], return_inverse=True)[1]
            means = np.bincount(groups, residual[inside]) / np.bincount(groups)
            centre.append(0.5 * (edges[b] + edges[b + 1]) if name != "fibre" else edges[b] + 0.5)
            mean.append(stats.trim_mean(residual[inside], 0.1))
            error.append(2 * means.std(ddof=1) / math.sqrt(len(means)) if len(means) > 1 else np.nan)
            flagged.append((name, round(float(edges[b]), 6)) in reported)
        centre, mean, error, flagged = map(np.asarray, (centre, mean, error, flagged))
        ax.errorbar(centre, mean, yerr=error, fmt="o-", ms=3.5, lw=1, color="#3465a4", ecolor="#9db4d6")
        if flagged.any():
            ax.plot(centre[flagged], mean[flagged], "o", ms=6, color="#cc0000", label="reported bin")
            ax.legend(loc="best", fontsize=7)
        ax.axhline(0.0, color="#888", lw=0.8)
        ax.set_xlabel(UNITS[name], fontsize=8)
        ax.set_ylabel("binned residual [cm]", fontsize=8)
        ax.tick_params(labelsize=7)
    text = axes.flat[len(values)]
    text.axis("off")
    energy = diagnosis["energy_cm2"]
    text.text(0.0, 0.95, "\n".join([
        f"{run.name}", f"{len(residual):,} pairs of the nominal-model fit",
        f"J before {energy['before']:.3g} cm², after {energy['after']:.3g} cm²",
        f"findings: {len(diagnosis['findings'])}",
        "points: trimmed mean per bin, less the field's",
        "bars: ±2 standard errors of cluster means",
        "red: bins diagnosis.json reports"]), va="top", fontsize=8)
    for ax in list(axes.flat)[len(values) + 1:]:
        ax.axis("off")
    figure.suptitle(f"{run.name}: residuals of the nominal model, binned against each regressor", fontsize=10)
    figure.tight_layout()
    figure.savefig(out, dpi=DPI)
    plt.close(figure)


def discovered_figure(run: Path, diagnosis: dict, out: Path) -> None:
    """Each discovered curve with its 1-sigma band (left) and, when diagnosis.json carries them, the residuals
    binned against its regressor before and after it was modelled (right)."""
    found = [f for f in diagnosis["findings"] if f["effect"] == "discovered"]
    figure, axes = plt.subplots(len(found), 2, figsize=(10.5, 3.2 * len(found)), squeeze=False)
    for (ax, binned), finding in zip(axes, found):
        curve = finding["curve"]
        x, y = np.asarray(curve["x"], float), np.asarray(curve["y"], float)
        sigma = np.asarray(curve["sigma"], float)
        scale, unit = (100.0, "cm") if finding["unit"] == "m" else (1.0, finding["unit"])
        ax.fill_between(x, scale * (y - sigma), scale * (y + sigma), color="#3465a4", alpha=0.25, label="1σ band")
        ax.plot(x, scale * y, color="#3465a4", label="estimate (constant removed)")
        ax.axhline(0.0, color="#888", lw=0.8)
        energy = finding["energy_cm2"]
        ax.set_title(f"{finding['channel']} error against {finding['regressor']}: held-out J "
                     f"{energy['held_out_before']:.3g} → {energy['held_out_after']:.3g} cm²", fontsize=9)
        xlabel = CURVE_AXES.get(finding["regressor"], finding["regressor"])
        ax.set_xlabel(xlabel, fontsize=8)
        ax.set_ylabel(f"{finding['channel']} error [{unit}]", fontsize=8)
        ax.legend(loc="best", fontsize=7)
        rows = finding.get("binned_residual_cm")
        if rows:
            for label, colour in (("before", "#cc0000"), ("after", "#4e9a06")):
                effect = np.array([np.nan if v is None else v for v in rows[label]["effect_cm"]], float)
                binned.plot(rows[label]["x"], effect, "o-", ms=3.5, color=colour, label=f"{label} it was modelled")
            binned.axhline(0.0, color="#888", lw=0.8)
            binned.legend(loc="best", fontsize=7)
            binned.set_title(f"residuals binned against {finding['regressor']}: J {energy['before']:.3g} → "
                             f"{energy['after']:.3g} cm²", fontsize=9)
            binned.set_xlabel(f"{xlabel} (bin centre)", fontsize=8)
            binned.set_ylabel("binned residual [cm]", fontsize=8)
        else:
            binned.axis("off")
        for a in (ax, binned):
            a.tick_params(labelsize=7)
    figure.suptitle(f"{run.name}: discovered effects (diagnosis.json)", fontsize=10)
    figure.tight_layout()
    figure.savefig(out, dpi=DPI)
    plt.close(figure)


def _label(effect: str) -> str:
    """A discrepancy 'range~incidence/6/...' as 'range ~ incidence'."""
    return effect.split("/")[0].replace("~", " ~ ")


def tests_figure(run: Path, diagnosis: dict, out: Path) -> None:
    """Each candidate's first-round statistic per degree of freedom, coloured by its verdict."""
    rows = sorted(diagnosis["candidates"], key=lambda c: -(c["statistic"] or 0.0) / c["dof"])
    verdicts = {"significant, plausible": "#4e9a06", "significant, beyond its physical size": "#f57900",
                "not significant": "#888a85", "not observable (concealed)": "#d3d7cf"}
    colours, values = [], []
    for c in rows:
        if c["concealment_r2"] is not None and c["concealment_r2"] > 0.995:
            verdict = "not observable (concealed)"
        elif c["significant"]:
            verdict = "significant, plausible" if c["plausible"] else "significant, beyond its physical size"
        else:
            verdict = "not significant"
        colours.append(verdicts[verdict])
        values.append(max((c["statistic"] or 0.0) / c["dof"], 1e-1))
    figure, ax = plt.subplots(figsize=(8, 0.22 * len(rows) + 1.3))
    ax.barh(range(len(rows)), values, color=colours)
    ax.set_yticks(range(len(rows)), [_label(c["effect"]) for c in rows], fontsize=7)
    ax.invert_yaxis()
    ax.set_xscale("log")
    ax.set_xlabel("score statistic T / dof (robust variance factor; 0 drawn at 0.1)", fontsize=8)
    ax.tick_params(axis="x", labelsize=7)
    for dof, style in ((1, "--"), (4, "-."), (8, ":")):
        critical = stats.chi2.isf(ALPHA / len(rows), dof) / dof
        ax.axvline(critical, color="#204a87", ls=style, lw=1, label=f"p = 0.001/{len(rows)} at {dof} dof")
    for verdict, colour in verdicts.items():
        ax.barh([0], [0], color=colour, label=verdict)
    ax.legend(loc="lower right", fontsize=7)
    ax.set_title(f"{run.name}: first-round test of every candidate (diagnosis.json)", fontsize=9)
    figure.tight_layout()
    figure.savefig(out, dpi=DPI)
    plt.close(figure)


def motion_figure(recording: Path, out: Path) -> None:
    """Per revolution: the rigid motion onto the first five revolutions, and the share of changed ranges."""
    import open3d as o3d
    import pyarrow.parquet as pq
    from scipy.spatial.transform import Rotation

    points = pq.read_table(recording / "points.parquet", columns=["time", "fibre", "range", "azimuth", "scan"])
    points = {name: points[name].to_numpy() for name in points.column_names}
    sensor = yaml.safe_load((recording / "sensor.yaml").read_text())
    elevation = np.radians([fibre["elevation_deg"] for fibre in sensor["fibres"]])[points["fibre"]]
    r, a = points["range"].astype(np.float64), points["azimuth"].astype(np.float64)
    xyz = np.column_stack([r * np.cos(elevation) * np.cos(a), -r * np.cos(elevation) * np.sin(a),
                           r * np.sin(elevation)])
    scan, fibre, t = points["scan"], points["fibre"], points["time"] - points["time"].min()
    scans = np.unique(scan)[1:-1]  # the first and the last revolution are partial
    first = np.isin(scan, scans[:5]) & (r > 0.5)
    reference = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz[first])).voxel_down_sample(0.05)
    reference.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.3, max_nn=30))
    azimuth = np.degrees(a)
    profile = {}
    for k in np.unique(fibre):
        of = first & (fibre == k)
        cell, inverse = np.unique(np.round(azimuth[of] / 0.05).astype(int), return_inverse=True)
        profile[k] = (cell * 0.05, np.array([np.median(r[of][inverse == c]) for c in range(len(cell))]))
    changed = np.full(len(r), False)
    for k, (grid, median) in profile.items():
        of = fibre == k
        changed[of] = np.abs(r[of] - np.interp(azimuth[of], grid, median, period=360.0)) > 0.2
    rows = []
    for s in scans[5:]:
        of = (scan == s) & (r > 0.5)
        source = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz[of]))
        result = o3d.pipelines.registration.registration_icp(
            source, reference, 0.3, np.eye(4), o3d.pipelines.registration.TransformationEstimationPointToPlane(),
            o3d.pipelines.registration.ICPConvergenceCriteria(max_iteration=60))
        T = result.transformation
        yaw = Rotation.from_matrix(T[:3, :3].copy()).as_euler("xyz", degrees=True)[2]
        rows.append([np.median(t[scan == s]), *(T[:3, 3] * 100), yaw, changed[scan == s].mean() * 100,
                     result.inlier_rmse * 100])
    rows = np.array(rows)
    figure, (left, middle, right) = plt.subplots(1, 3, figsize=(12, 3.3))
    for i, label in ((1, "x"), (2, "y"), (3, "z")):
        left.plot(rows[:, 0], rows[:, i], "o-", ms=3, label=label)
    left.set(xlabel="time [s]", ylabel="translation [cm]", title="revolution onto the first five: translation")
    left.legend(fontsize=7)
    middle.plot(rows[:, 0], rows[:, 4], "o-", ms=3, color="#cc0000")
    middle.set(xlabel="time [s]", ylabel="yaw [deg]", title="... and yaw")
    right.plot(rows[:, 0], rows[:, 5], "o-", ms=3, color="#555753")
    right.set(xlabel="time [s]", ylabel="returns [%]", title="ranges changed by > 20 cm")
    for ax in (left, middle, right):
        ax.axhline(0.0, color="#888", lw=0.8)
        ax.tick_params(labelsize=7)
        ax.title.set_fontsize(9)
        ax.xaxis.label.set_fontsize(8)
        ax.yaxis.label.set_fontsize(8)
    figure.suptitle(f"{recording.name}: is the head at rest? (ICP of each revolution, catalogue model)", fontsize=10)
    figure.tight_layout()
    figure.savefig(out, dpi=DPI)
    plt.close(figure)
    for row in rows:
        print(f"  t {row[0]:5.2f} s  x {row[1]:+5.1f} y {row[2]:+5.1f} z {row[3]:+5.1f} cm  yaw {row[4]:+6.3f} deg  "
              f"changed {row[5]:4.1f} %  ICP rmse {row[6]:.1f} cm")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("runs", nargs="*", type=Path, help="diagnose run folders (default: /tmp/real_runs/*)")
    parser.add_argument("--no-binned", action="store_true", help="only the figures made from diagnosis.json")
    parser.add_argument("--motion", type=Path, action="append", default=[],
                        help="a recording folder: also check that its head is at rest (<name>_motion.png)")
    args = parser.parse_args()
    runs = args.runs or sorted(p for p in RUNS.iterdir() if (p / "diagnosis.json").is_file())
    OUT.mkdir(parents=True, exist_ok=True)
    for recording in args.motion:
        print(f"{recording.name}: motion check")
        motion_figure(recording, OUT / f"{recording.name}_motion.png")
    for run in runs:
        diagnosis = json.loads((run / "diagnosis.json").read_text())
        if any(f["effect"] == "discovered" for f in diagnosis["findings"]):
            discovered_figure(run, diagnosis, OUT / f"{run.name}_discovered.png")
        else:
            tests_figure(run, diagnosis, OUT / f"{run.name}_tests.png")
        if not args.no_binned:
            binned_figure(run, diagnosis, OUT / f"{run.name}_binned.png")
        print(f"{run.name}: figures written to {OUT}")


if __name__ == "__main__":
    main()
