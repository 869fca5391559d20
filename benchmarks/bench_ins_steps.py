"""Benchmark: an INS that both steps and carries white noise, calibrated with the steps kept and with them smoothed
over.

city_loop for `--minutes` at `--size` (5 mm range noise, seed 0), its drifting INS with GNSS-like jumps
(`--jump-rate` a second, 3 cm per axis) and white noise of 5 mm and 0.005 deg a sample (100 Hz), calibrated with the
defaults and FAR_START_PRIORS twice: as graphcal runs (the smoothing of the white noise runs on either side of each
step it finds, trajectory_steps.noisy_steps, and a control stands on each side of each step), and with
noisy_steps finding nothing (one spline over the whole drive spreads each step over its window, and no step is
left for the controls: what graphcal did before). Figures per case: the steps found, seconds, peak memory, the
trajectory's error against the truth at the control times (bench_long_drive's) and over every INS sample (the
smoothed poses plus the corrections interpolated between controls, the common translation removed), the intrinsic
and extrinsic errors, the extrinsic's 1-sigmas (reported, and each of the model's, the shared returns' and the
cluster-robust ones), the parameters named unobservable, the gauge-free cloud-to-cloud distance. Writes
benchmarks/results/ins_steps.json.
"""

from __future__ import annotations

import argparse
import datetime
import time
from pathlib import Path

from bench_long_drive import _trajectory_errors_cm
from common import extrinsic_sigmas, machine, peak_gib, report, run_in_process

RESULTS = Path(__file__).resolve().parent / "results"
CASES = ("steps kept", "steps smoothed over")


def _drive(folder: Path, minutes: float, size: float, jump_rate_hz: float) -> Path:
    """The drive (module docstring), simulated into folder unless it is there."""
    from graphcal.simulation.script import load_scenario_builder
    from graphcal.simulation.simulator import simulate_to

    drive = folder / f"city_{minutes:g}min_size{size:g}_noisy_ins_jumps{jump_rate_hz:g}"
    if not (drive / "recording.yaml").exists():
        scenario = load_scenario_builder("city_loop")(duration_s=60.0 * minutes, size=size, seed=0, range_noise_m=0.005)
        ins = scenario.ins.model_copy(update={"jump_rate_hz": jump_rate_hz, "position_noise_m": 0.005,
                                              "attitude_noise_deg": 0.005})
        simulate_to(scenario.model_copy(update={"ins": ins}), drive, quiet=True)
    return drive


def _case(folder: str, case: str, queue) -> None:
    import numpy as np

    import graphcal
    import graphcal.recording.trajectory_noise as trajectory_noise
    from graphcal.calibration.evaluate import evaluate
    from graphcal.calibration.returns import resampled
    from graphcal.recording.geodesy import to_world
    from graphcal.simulation.starts import FAR_START_PRIORS

    if case == "steps smoothed over":
        trajectory_noise.noisy_steps = lambda position_m: np.zeros(0, np.int64)
    recording = graphcal.Recording.load(folder)
    started = time.perf_counter()
    result = graphcal.calibrate(recording, graphcal.CalibrationConfig(priors=FAR_START_PRIORS), quiet=True)
    seconds = time.perf_counter() - started
    times = np.asarray(result.calibration.control_times_s)
    poses, true = recording.world.poses, to_world(recording.truth.trajectory, recording.crs).poses
    inside = (poses.time >= times[0]) & (poses.time <= times[-1])
    corrections = resampled(result.calibration.estimate.corrections, times, poses.time[inside])  # eq. 5.4
    final = poses.position_m[inside] + np.array([c.translation() for c in corrections])
    error = final - true.interpolate(poses.time[inside])[0]
    error_cm = np.linalg.norm(error - error.mean(axis=0), axis=1) * 100
    evaluation = evaluate(result, recording)
    queue.put({"steps_found_s": [round(float(t), 2) for t in result.ins_steps_s[:, 0]], "seconds": round(seconds, 1),
               "peak_gib": round(peak_gib(), 2), "trajectory_at_controls": _trajectory_errors_cm(result, recording),
               "trajectory_every_sample_cm": {"rms": round(float(np.sqrt(np.mean(error_cm ** 2))), 3),
                                              "p99": round(float(np.percentile(error_cm, 99)), 3)},
               "intrinsic_rms_after (cm, deg, deg, cm)": [round(float(v), 5) for v in evaluation.intrinsic_rms_after],
               "lever_arm_error_cm": round(float(evaluation.lever_arm_error_m[1]) * 100, 3),
               "extrinsic_sigma": {name: extrinsic_sigmas(getattr(result, field).extrinsic) for name, field in
                                   (("reported", "sigmas"), ("model", "uncertainty"),
                                    ("shared_returns", "shared_returns_uncertainty"),
                                    ("cluster_robust", "cluster_robust_uncertainty"))
                                   if getattr(result, field) is not None},
               "unobservable": list(result.calibration.unobservable),
               "rotation_error_deg": round(float(evaluation.rotation_error_deg[1]), 4),
               "c2c_mean_gauge_free_cm": round(evaluation.cloud_after_gauge_free.mean * 100, 3)})


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--minutes", type=float, default=2.0)
    parser.add_argument("--size", type=float, default=0.05)
    parser.add_argument("--jump-rate", type=float, default=0.1, help="GNSS-like jumps a second (city_loop's: 1/30)")
    parser.add_argument("--keep", type=Path, required=True, help="folder where the drive is simulated and kept")
    args = parser.parse_args()
    drive = _drive(args.keep, args.minutes, args.size, args.jump_rate)
    figures = {"machine": machine(), "date": datetime.date.today().isoformat(), "arguments": vars(args) | {
        "keep": str(args.keep)}}
    for case in CASES:
        figures[case] = run_in_process(_case, str(drive), case)
    RESULTS.mkdir(exist_ok=True)
    report(figures, RESULTS / "ins_steps.json")


if __name__ == "__main__":
    main()
