"""Benchmark: calibrate simulated scenarios and compare with truth (issue 3 acceptance figures).

Cases: sim2_street intrinsic from the Table 4.1 start (noise-free), sim6_turn trajectory
(translation corrections). Each case runs in its own process (its own peak memory). Prints the
figures and writes benchmarks/results/calibrate.json.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import platform
import resource
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
CASES = {"sim2_intrinsic": ("sim2_street", {"mode": "intrinsic"}),
         "sim6_trajectory": ("sim6_turn", {"mode": "trajectory"}),
         "sim6_joint_trajectory": ("sim6_turn", {"mode": "joint_trajectory"})}


def _case(name: str, size: float, max_points: int | None, queue) -> None:
    import graphcal
    from graphcal.sim.script import load_scenario_builder

    scenario_name, settings = CASES[name]
    recording = graphcal.simulate(load_scenario_builder(scenario_name)(size=size, seed=0), quiet=True)
    started = time.perf_counter()
    result = graphcal.calibrate(recording, graphcal.CalibrationConfig(**settings, max_points=max_points), quiet=True)
    seconds = time.perf_counter() - started
    evaluation = graphcal.evaluate(result, recording)
    queue.put({"case": name, "returns": len(recording.points), "max_points": max_points, "calibrate_s": seconds,
               "peak_gib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20,
               "outer_iterations": len(result.history), "unobservable": list(result.unobservable),
               "intrinsic_rms_after_cm_deg_deg_cm": evaluation.intrinsic_rms_after.tolist(),
               "energy_cm2": list(evaluation.energy_cm2),
               "c2c_mean_cm": [evaluation.cloud_before.mean * 100, evaluation.cloud_after.mean * 100],
               "c2c_mean_no_common_offset_cm": evaluation.cloud_after_gauge_free.mean * 100,
               "table": evaluation.table()})


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=float, default=1.0, help="fraction of firings (1 = full size)")
    parser.add_argument("--max-points", type=int, default=None, help="returns used by the calibration")
    parser.add_argument("--cases", nargs="*", default=list(CASES), choices=list(CASES))
    args = parser.parse_args()
    figures = []
    for name in args.cases:
        queue = mp.get_context("spawn").Queue()
        process = mp.get_context("spawn").Process(target=_case, args=(name, args.size, args.max_points, queue))
        process.start()
        figures.append(queue.get())
        process.join()
        row = figures[-1]
        print(f"{name}: {row['returns']:,} returns, calibrate {row['calibrate_s']:.1f} s, peak {row['peak_gib']:.2f} GiB, "
              f"{row['outer_iterations']} outer iterations\n{row['table']}\nunobservable: {row['unobservable']}\n")
    RESULTS.mkdir(exist_ok=True)
    out = RESULTS / "calibrate.json"
    tmp = out.with_suffix(".json.tmp")
    tmp.write_text(json.dumps({"machine": platform.platform(), "size": args.size, "cases": figures}, indent=2))
    tmp.replace(out)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
