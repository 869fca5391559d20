"""Benchmark: the mismatch finder (graphcal.diagnose) on recordings it was not fitted to.

The independent simulator (tools/foreign_sim) fires its lasers in its own order inside a block, gives
the encoder a per-revolution error, draws intensity from reflectivity, incidence and distance, adds white
INS noise, and carries true intrinsic and extrinsic errors; on top of that each case switches on
departures (tools/foreign_sim/departures.py) that graphcal's candidates name, written from their
physics there, not from graphcal's definitions. Each case is a box_street drive (--mount, level by default; 16 s)
diagnosed with the calibration mode the effect needs (joint: intrinsics and extrinsic; the candidates
are then what is left), named candidates only unless --open-world, on max_points returns, the baseline
stopped after at most 6 outer iterations (as bench_diagnose.py); a baseline the calibration refuses is
recorded as refused.

Cases (each in its own process, its own peak memory): clean (nothing named is expected), one per
departure, and `two` (latency and range scale together). Figures: the findings in order, whether each
injected effect is named first (or among the first n for n injected), its size against
truth/effects.yaml (error %), the first round's test of it, the candidates not separated, withdrawn,
the seconds and the peak memory. Prints them and writes benchmarks/results/diagnose_foreign.json (or --out).
"""

from __future__ import annotations

import argparse
import datetime
import json
import sys
import tempfile
import time
from pathlib import Path

from common import machine, peak_gib, report, run_in_process

RESULTS = Path(__file__).resolve().parent / "results"
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tools.foreign_sim, from the checkout

# the departures of each case (tools.foreign_sim.Departures' fields), modest against the 1 cm range noise
CASES = {
    "clean": {},
    "range_scale": {"range_scale": 0.0015},
    "azimuth_eccentricity": {"eccentricity_deg": 0.06, "eccentricity_phase_deg": 30.0},
    "time_offset": {"latency_s": 0.008},
    "heading_drift": {"heading_drift_deg_s": 0.02},
    "incidence_range_bias": {"incidence_range_bias_m": 0.04},
    "intra_sweep_motion": {"revolution_stamps": True},
    "two": {"latency_s": 0.006, "range_scale": 0.0012},
}
# truth/effects.yaml entries that are not departures a candidate names (or, at magnitude 0, not there at all)
NOT_INJECTED = ("encoder_jitter", "ins_position_drift", "ins_attitude_drift")


def injected(effects: dict) -> dict[str, float]:
    """The named effects a recording carries (truth/effects.yaml), with their magnitudes in the finder's unit."""
    return {name: float(entry["magnitude"]) for name, entry in effects.items()
            if name not in NOT_INJECTED and entry["magnitude"] != 0}


def _config(max_points: int, outer_iterations: int):
    from graphcal.calibration.config import CalibrationConfig

    return CalibrationConfig(mode="joint", max_points=max_points, stopping={
        "max_outer_iterations": outer_iterations, "tolerance_m": 1e-4, "refuse_unconverged": False})


def _case(name: str, mount: str, size: float, duration_s: float, seed: int, max_points: int, outer_iterations: int,
          open_world: bool, queue) -> None:
    import graphcal
    from graphcal.common.errors import CalibrationError
    from tools.foreign_sim import Departures, simulate

    with tempfile.TemporaryDirectory() as folder:
        directory = simulate("box_street", Path(folder) / name, duration_s=duration_s, size=size, seed=seed,
                             mount=mount, departures=Departures(**CASES[name]))
        recording = graphcal.Recording.load(directory)
        truth = injected(recording.truth.effects)
        started = time.perf_counter()
        try:
            diagnosis = graphcal.diagnose(recording, _config(max_points, outer_iterations),
                                          max_effects=len(truth) + 1, quiet=True, open_world=open_world)
        except CalibrationError as error:  # the baseline calibration refused the recording
            queue.put({"returns": len(recording.points), "injected": truth, "refused": str(error),
                       "seconds": round(time.perf_counter() - started, 1), "peak_gib": round(peak_gib(), 2)})
            return
        seconds = time.perf_counter() - started
    named = [f["effect"] if f["effect"] != "discovered" else f"discovered {f['channel']} x {f['regressor']}"
             for f in diagnosis.findings]
    row = {"returns": len(recording.points), "seconds": round(seconds, 1), "peak_gib": round(peak_gib(), 2),
           "injected": truth, "named": named, "nothing_named": not named and not truth,
           "not_separable": [n["effects"] for n in diagnosis.not_separable],
           "withdrawn": [w["effect"] for w in diagnosis.withdrawn],
           "energy_cm2": diagnosis.energy_cm2, "summary": diagnosis.summary()}
    found = {f["effect"]: f for f in diagnosis.findings}
    for effect, true in truth.items():
        entry = {"true": true, "named_first": effect in named[:len(truth)]}
        if effect in found:
            entry |= {"magnitude": found[effect]["magnitude"], "sigma": found[effect]["sigma"],
                      "error_pct": round(100 * (found[effect]["magnitude"] - true) / true, 1)}
        first = next((c for c in diagnosis.candidates if c["effect"] == effect), None)
        if first is not None:
            entry["first_round"] = {k: first[k] for k in ("magnitude", "sigma", "mdb", "statistic", "significant",
                                                          "plausible", "bic_gain", "concealment_r2", "absorbed_by")}
        row[effect] = entry
    queue.put(row)


def main() -> None:
    from graphcal.common.atomic import atomic_path

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=float, default=0.1, help="fraction of the head's firings simulated")
    parser.add_argument("--duration", type=float, default=16.0, help="seconds of drive")
    parser.add_argument("--seed", type=int, default=0, help="the simulator's seed (scene, drive, offsets, noise)")
    parser.add_argument("--mount", choices=("level", "tilted"), default="level",
                        help="the head level on the roof, or pitched 12 deg on its mount")
    parser.add_argument("--max-points", type=int, default=80_000, help="returns each diagnosis uses")
    parser.add_argument("--outer-iterations", type=int, default=6, help="the baseline's outer iterations at most")
    parser.add_argument("--open-world", action="store_true", help="also the generic discrepancies (default: named "
                                                                      "candidates only)")
    parser.add_argument("--cases", nargs="*", default=list(CASES), choices=list(CASES))
    parser.add_argument("--out", type=Path, default=RESULTS / "diagnose_foreign.json")
    args = parser.parse_args()
    figures = {"machine": machine(),
               "date": datetime.date.today().isoformat(),
               "settings": {"family": "box_street", "mount": args.mount, "size": args.size, "duration_s": args.duration,
                            "seed": args.seed, "max_points": args.max_points, "mode": "joint",
                            "max_outer_iterations": args.outer_iterations,
                            "open_world": args.open_world},
               "departures": {case: CASES[case] for case in args.cases}, "cases": {}}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    for case in args.cases:  # the figures written after each case: a long run keeps what it measured
        print(f"running {case} ...", flush=True)
        figures["cases"][case] = run_in_process(_case, case, args.mount, args.size, args.duration, args.seed, args.max_points,
                                                 args.outer_iterations, args.open_world)
        print(json.dumps(figures["cases"][case], indent=1), flush=True)
        with atomic_path(args.out) as tmp:
            tmp.write_text(json.dumps(figures, indent=2))
    report(figures, args.out)


if __name__ == "__main__":
    main()
