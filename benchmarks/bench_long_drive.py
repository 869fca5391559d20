"""Benchmark: calibrating long drives (scenarios/city_loop.py: a district driven in loops, every street passed
both ways about every 4 minutes, an INS drifting as a GNSS-aided one does) of 1, 2, 5 and 10 minutes.

Each drive is simulated straight to disk (graphcal.simulation.simulator.simulate_to, flat memory) at a stated
size (the fraction of firings kept: the machine's time, not graphcal's, limits the simulation) and calibrated
with the defaults (mode auto: joint with trajectory corrections once the drive comes back) in its own process,
but the priors: city_loop's true sensor is Table 4.1's start (3 deg and 10 cm off the nominal), no factory
calibration, so the calibration states that uncertainty (FAR_START_PRIORS, as bench_calibrate.py does for
sim2_street); with the factory priors its rings, which do cross, are refused as crossed.
Figures per drive: returns, seconds per stage, peak memory, returns read per second, RMS intrinsic errors
before/after, extrinsic errors, trajectory error against the truth at the control times (the estimated
corrections less the true INS error, the common translation no self-calibration sees removed) next to the INS
error itself, and the cloud-to-cloud distance to the truth (or the refusal, when calibrate refuses its
result). Prints them and writes benchmarks/results/long_drive.json (--result).
"""

from __future__ import annotations

import datetime
import os
import tempfile
import time
from pathlib import Path

from common import city_loop_arguments, city_loop_drive, machine, peak_gib, report, run_in_process

RESULTS = Path(__file__).resolve().parent / "results"


def _trajectory_errors_cm(result, recording) -> dict:
    """RMS [cm] of the INS error and of the estimated corrections less it at the control times, each less its
    mean (the common translation), over every control and over the revisited ones (a position within
    REVISIT_WITHIN_M of one held at least REVISIT_AFTER_S apart, as calibrate's mode auto decides)."""
    import numpy as np
    from scipy.spatial import cKDTree

    from graphcal.calibration.returns import REVISIT_AFTER_S, REVISIT_WITHIN_M
    from graphcal.recording.geodesy import to_world

    times = np.asarray(result.calibration.control_times_s)
    recorded, true = recording.world.poses, to_world(recording.truth.trajectory, recording.crs).poses
    inside = (times >= max(recorded.span[0], true.span[0])) & (times <= min(recorded.span[1], true.span[1]))
    position_m = true.interpolate(times[inside])[0]
    ins_error = position_m - recorded.interpolate(times[inside])[0]
    corrections = np.array([c.translation() for c in result.calibration.estimate.corrections])[inside]
    left = corrections - ins_error
    left -= left.mean(axis=0)
    drift = ins_error - ins_error.mean(axis=0)
    near = cKDTree(position_m).query_ball_point(position_m, REVISIT_WITHIN_M)
    revisited = np.array([any(abs(times[inside][k] - times[inside][j]) >= REVISIT_AFTER_S for j in close)
                          for k, close in enumerate(near)], bool)

    def rms_cm(error_m):
        return round(float(np.sqrt(np.mean(np.sum(error_m ** 2, axis=1)))) * 100, 2) if len(error_m) else None

    return {"controls": int(inside.sum()), "ins_error_rms_cm": rms_cm(drift), "after_rms_cm": rms_cm(left),
            "revisited_controls": int(revisited.sum()), "revisited_ins_error_rms_cm": rms_cm(drift[revisited]),
            "revisited_after_rms_cm": rms_cm(left[revisited])}


def _case(folder: str, max_points: int | None, seed: int, queue) -> None:
    import graphcal
    from graphcal.calibration.evaluate import evaluate
    from graphcal.simulation.starts import FAR_START_PRIORS

    recording = graphcal.Recording.load(folder)
    started = time.perf_counter()
    try:
        config = graphcal.CalibrationConfig(max_points=max_points, seed=seed, priors=FAR_START_PRIORS)
        result = graphcal.calibrate(recording, config, quiet=True)
    except graphcal.CalibrationError as error:  # a refused result is a figure too
        queue.put({"returns": len(recording.points), "seconds": round(time.perf_counter() - started, 1),
                   "peak_gib": round(peak_gib(), 2), "refused": str(error).split(": ", 1)[-1]})
        return
    seconds = time.perf_counter() - started
    out = {"returns": len(recording.points), "mode": result.config.mode, "seconds": round(seconds, 1),
           "returns_per_s": round(len(recording.points) / seconds),
           "peak_gib": round(peak_gib(), 2), "outer_iterations": len(result.history),
           "outer_iterations_per_phase": {phase: sum(row["phase"] == phase for row in result.history)
                                          for phase in ("coarse", "fine")},
           "seconds_per_stage": {k: round(v, 1) for k, v in result.timings_s.items()},
           "energy_cm2": [round(float(e), 5) for e in result.energy_cm2]}
    evaluation = evaluate(result, recording)
    out |= {"intrinsic_rms_before (cm, deg, deg, cm)": [round(float(v), 5) for v in evaluation.intrinsic_rms_before],
            "intrinsic_rms_after (cm, deg, deg, cm)": [round(float(v), 5) for v in evaluation.intrinsic_rms_after],
            "lever_arm_error_m (before, after)": [round(float(v), 4) for v in evaluation.lever_arm_error_m],
            "rotation_error_deg (before, after)": [round(float(v), 4) for v in evaluation.rotation_error_deg],
            "c2c_mean_cm (before, after, gauge-free)": [round(evaluation.cloud_before.mean * 100, 2),
                                                        round(evaluation.cloud_after.mean * 100, 2),
                                                        round(evaluation.cloud_after_gauge_free.mean * 100, 2)]}
    if result.config.mode.endswith("trajectory"):
        out["trajectory"] = _trajectory_errors_cm(result, recording)
        named = [name for name in result.unobservable if name.startswith("control_")]
        out["trajectory"]["controls_named"] = len({name.partition(".")[0] for name in named})
        out["trajectory"]["components_named"] = {axis: sum(name.endswith(f".{axis}") for name in named)
                                                 for axis in ("x_m", "y_m", "z_m")}
    queue.put(out)


def main() -> None:
    args = city_loop_arguments(__doc__, [1, 2, 5, 10], 0.1, "long_drive.json")
    from graphcal.simulation.starts import FAR_START_PRIORS

    figures = {"machine": machine(),
               "date": datetime.date.today().isoformat(), "size": args.size, "max_points": args.max_points,
               "seed": args.seed, "priors": FAR_START_PRIORS, "drives": {}}
    for minutes in args.minutes:
        with tempfile.TemporaryDirectory() as folder:
            drive, simulated_s = city_loop_drive(args.keep or folder, minutes, args.size)
            figures["drives"][f"{minutes:g} min"] = {"simulated_s": simulated_s,
                                                     "load_average_1min": round(os.getloadavg()[0], 2),
                                                     **run_in_process(_case, str(drive), args.max_points, args.seed)}
        RESULTS.mkdir(exist_ok=True)
        report(figures, RESULTS / args.result)


if __name__ == "__main__":
    main()
