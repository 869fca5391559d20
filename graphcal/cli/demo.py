"""Flagship demo, end to end: simulate sim6_turn (an INS with a piecewise-linear position error
blurs the cloud), calibrate the trajectory corrections, compare with the truth, write the viewer
file and the report, and say what to open.

    OUT/recording/      the simulated recording (with truth/)
    OUT/                the run folder: calibration.yaml, report.html, run.rrd, run.yaml ...
"""

from __future__ import annotations

import time
from pathlib import Path

from graphcal.calibration.config import CalibrationConfig
from graphcal.cli.runs import calibration_run
from graphcal.simulation.script import load_scenario_builder
from graphcal.simulation.simulator import simulate

SIZE = 0.5  # half the firings of the full drive: ~1.9 M returns
MAX_POINTS = 250_000  # returns the calibration draws (seeded)
VIEWER_POINTS = 500_000
EVALUATION_POINTS = 200_000  # cloud-to-cloud from this many random returns to the whole true cloud


def run_demo(out: Path, size: float = SIZE, max_points: int = MAX_POINTS, max_outer_iterations: int | None = None,
             spawn: bool = False, quiet: bool = False) -> dict:
    """Returns the figures it prints: returns, seconds per step, J and cloud-to-cloud [m] before/after."""
    out = Path(out)
    started = time.perf_counter()
    recording = simulate(load_scenario_builder("sim6_turn")(size=size, seed=0), quiet=quiet)
    recording.save(out / "recording")
    simulated = time.perf_counter()
    config = CalibrationConfig(mode="trajectory", max_points=max_points)
    if max_outer_iterations is not None:  # a quick look: stopped on its cap, returned unchecked
        config = config.with_settings(stopping={"max_outer_iterations": max_outer_iterations,
                                                "refuse_unconverged": False})
    run = calibration_run(out / "recording", config, out, spawn=spawn, viewer_points=VIEWER_POINTS,
                          evaluation_points=EVALUATION_POINTS, command="demo", quiet=quiet)
    finished = time.perf_counter()
    evaluation = run.evaluation
    figures = {"returns": len(recording.points), "simulate_s": simulated - started, "calibrate_s": run.result.seconds,
               "total_s": finished - started, "energy_cm2": run.result.energy_cm2,
               "cloud_before": evaluation.cloud_before, "cloud_after": evaluation.cloud_after,
               "cloud_after_gauge_free": evaluation.cloud_after_gauge_free, "folder": run.folder}
    if not quiet:
        _print(figures, config, run.result, evaluation)
    return figures


def _print(figures: dict, config: CalibrationConfig, result, evaluation) -> None:
    before, after = figures["energy_cm2"]
    folder = figures["folder"]
    print(f"simulated sim6_turn: {figures['returns']:,} returns, an INS with a 0.35 m piecewise-linear position "
          f"error, in {figures['simulate_s']:.1f} s -> {folder / 'recording'}")
    print(f"calibrated the trajectory (mode {config.mode}, {config.max_points:,} returns drawn, "
          f"{len(result.history)} outer iterations) in {figures['calibrate_s']:.1f} s: J {before:.3g} -> {after:.3g} cm^2")
    print(evaluation.cloud_line())
    print(f"done in {figures['total_s']:.0f} s. Open:")
    print(f"  {folder / 'report.html'}   (in a browser: J curve, residuals, parameters, errors, timings)")
    print(f"  graphcal view {folder}   (or: rerun {folder / 'run.rrd'}; no screen: graphcal view {folder} --web)")
