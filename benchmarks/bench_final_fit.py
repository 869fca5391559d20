"""Benchmark: the final fit and its covariances (Problem.final: the strict pairs at the estimate, the model's
marginals and the two sandwiches, shared returns and clustered by time) on city_loop drives of 10 and 60 minutes.

What grows with the drive there is the trajectory's keys (one control a second: 130 + 6 x 601 columns at ten
minutes, 130 + 6 x 3 601 at an hour), not the returns used (capped at --max-points). The drives are simulated
straight to disk at a small size (the fraction of firings kept: the simulation's time, not the fit's, limits it)
and the fit is made at the truth (true intrinsics and extrinsic, the INS's true error at the control times
as the trajectory corrections) in the mode calibrate
chooses for them (joint with trajectory corrections), each in its own process. Figures per drive: the columns,
the pairs, the seconds of the final fit, the peak memory before it and after it, and the median sigmas (to
compare versions). Prints them and writes benchmarks/results/final_fit.json (--result).
"""

from __future__ import annotations

import datetime
import subprocess
import tempfile
import time
import warnings
from pathlib import Path

from common import city_loop_arguments, city_loop_drive, machine, peak_gib, report, run_in_process

RESULTS = Path(__file__).resolve().parent / "results"


def _case(folder: str, max_points: int, seed: int, queue) -> None:
    from dataclasses import replace

    import gtsam
    import numpy as np

    import graphcal
    from graphcal.calibration.problem import Problem
    from graphcal.calibration.returns import initial_estimate, pose_of
    from graphcal.recording.geodesy import to_world
    from graphcal.simulation.starts import FAR_START_PRIORS

    recording = graphcal.Recording.load(folder)
    config = graphcal.CalibrationConfig(max_points=max_points, seed=seed, priors=FAR_START_PRIORS)
    problem = Problem.of(recording, config)
    times = problem.full.control_times_s  # the true trajectory corrections: the INS's error at the control times
    error_m = (to_world(recording.truth.trajectory, recording.crs).poses.interpolate(times)[0]
               - recording.world.poses.interpolate(times)[0])
    truth = replace(initial_estimate(recording, problem.full), offsets=recording.truth.intrinsics,
                    extrinsic=pose_of(recording.truth.extrinsic),
                    corrections=tuple(gtsam.Pose3(gtsam.Rot3(), e) for e in error_m))
    before = peak_gib()
    started = time.perf_counter()
    final = problem.final(truth, None, True)
    seconds = time.perf_counter() - started
    robust = final.cluster_robust

    def median(sigmas):  # a column not estimated (NaN throughout): None
        if sigmas is None:
            return None
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            return [None if np.isnan(v) else round(float(v), 6) for v in np.nanmedian(sigmas, axis=0)]

    queue.put({"returns": len(recording.points), "mode": problem.config.mode,
               "controls": len(truth.corrections), "pairs": len(final.pairs), "seconds": round(seconds, 1),
               "peak_gib_before": round(before, 2), "peak_gib": round(peak_gib(), 2),
               "median_intrinsic_sigma (model, cluster-robust)": [median(final.uncertainty.intrinsics),
                                                                  median(robust and robust.intrinsics)],
               "median_control_sigma (model, cluster-robust)": [median(final.uncertainty.controls),
                                                                median(robust and robust.controls)]})


def main() -> None:
    args = city_loop_arguments(__doc__, [10, 60], 0.01, "final_fit.json")
    commit = subprocess.run(["git", "describe", "--always", "--dirty"], capture_output=True, text=True,
                            cwd=Path(__file__).parent).stdout.strip()
    figures = {"machine": machine(), "date": datetime.date.today().isoformat(), "commit": commit,
               "size": args.size, "max_points": args.max_points, "seed": args.seed, "drives": {}}
    for minutes in args.minutes:
        with tempfile.TemporaryDirectory() as folder:
            drive, _ = city_loop_drive(args.keep or folder, minutes, args.size)
            figures["drives"][f"{minutes:g} min"] = run_in_process(_case, str(drive), args.max_points, args.seed)
        RESULTS.mkdir(exist_ok=True)
        report(figures, RESULTS / args.result)


if __name__ == "__main__":
    main()
