"""Benchmark: the same drive calibrated with and without moving traffic (issue 26, "moving traffic").

sim2_street (a 6 s drive at 6 m/s down a 16 m street, the head pitched 20 deg) simulated twice with the same
seed, the same true calibration errors and the same range noise: without traffic, and with sim2_street's
STREET_TRAFFIC (cars overtaking and oncoming, pedestrians walking and crossing; scenarios/street_traffic.py).
--scenario city_loop: the first --duration seconds of city_loop instead, with and without its CITY_TRAFFIC
(vehicles overtaking, oncoming and crossing on the district's streets, pedestrians on its pavements).
The true sensor is off the nominal one as a factory calibration and a measured mounting are: intrinsic
offsets of 3 cm / 0.3 deg RMS (SECTION_4_5_2_ERRORS), the extrinsic off by 3/3/5 cm and 0.3/0.3/-0.3 deg.
Both are calibrated with graphcal.calibrate's defaults. Figures per case: the fraction of returns on moving
objects (truth/points.parquet's `moving`), the intrinsic RMS error per parameter type over all fibres and
over those not named unobservable (cm, deg, deg, cm), the extrinsic errors (lever arm over the observed axes
[cm], rotation [deg]), J before and after [cm^2], seconds and peak memory; then the ratio of each intrinsic
RMS with traffic to without (the target: within 1.1). Writes benchmarks/results/traffic.json (or --out).
"""

from __future__ import annotations

import argparse
import datetime
import platform
import tempfile
import time
from pathlib import Path

from common import peak_gib, report, run_in_process

RESULTS = Path(__file__).resolve().parent / "results"
TYPES = ("d_range_cm", "d_azimuth_deg", "d_elevation_deg", "h_z_cm")


def _scenario(traffic: bool, size: float, seed: int, range_noise_m: float, scenario: str, duration_s: float):
    from graphcal.simulation.script import load_scenario_builder
    from graphcal.simulation.starts import PITCHED_HEAD, SECTION_4_5_2_ERRORS

    extrinsic = PITCHED_HEAD.model_copy(update={"error_lever_arm_m": (0.03, 0.03, 0.05),
                                                "error_boresight_deg": (0.3, 0.3, -0.3)})
    more = {"duration_s": duration_s} if scenario == "city_loop" else {}
    street = load_scenario_builder(scenario)(size=size, seed=seed, range_noise_m=range_noise_m, traffic=traffic, **more)
    return street.model_copy(update={"extrinsic": extrinsic, "intrinsic_errors": SECTION_4_5_2_ERRORS})


def _case(traffic: bool, size: float, seed: int, range_noise_m: float, settings: dict, scenario: str,
          duration_s: float, queue) -> None:
    import numpy as np

    import graphcal
    from graphcal.calibration.evaluate import intrinsic_rms, scorecard
    from graphcal.common.errors import CalibrationError

    with tempfile.TemporaryDirectory() as folder:
        started = time.perf_counter()
        recording = graphcal.Recording.load(graphcal.simulate(_scenario(traffic, size, seed, range_noise_m, scenario, duration_s),
                                                              quiet=True).save(Path(folder) / "rec"))
        simulate_s = time.perf_counter() - started
        moving = recording.truth.moving()
        row = {"traffic": traffic, "seed": seed, "returns": len(recording.points),
               "moving_fraction": float(np.mean(moving)), "simulate_s": simulate_s}
        started = time.perf_counter()
        try:
            result = graphcal.calibrate(recording, graphcal.CalibrationConfig(**settings, seed=seed), quiet=True)
        except CalibrationError as error:
            queue.put(row | {"calibrate_s": time.perf_counter() - started, "refused": str(error), "peak_gib": peak_gib()})
            return
        seconds = time.perf_counter() - started
        evaluation = graphcal.evaluate(result, recording)
        card = scorecard(result, recording)
        truth = recording.truth.intrinsics
        rms_all = intrinsic_rms(result.calibration.estimate.offsets, truth, recording.sensor.reference_fibre)
        rms_start = intrinsic_rms(np.zeros_like(truth), truth, recording.sensor.reference_fibre)
    queue.put(row | {"mode": result.config.mode, "calibrate_s": seconds, "peak_gib": peak_gib(),
                     "outer_iterations": len(result.history),
                     "intrinsic_rms_start": dict(zip(TYPES, map(float, rms_start))),
                     "intrinsic_rms": dict(zip(TYPES, map(float, rms_all))),
                     "intrinsic_rms_observable": dict(zip(TYPES, map(float, card.rms_observable))),
                     "within_3_sigma": card.within_3_sigma, "named_fraction": card.named_fraction,
                     "unobservable": len(result.unobservable),
                     "lever_arm_error_cm": [e * 100 for e in evaluation.lever_arm_error_m],
                     "rotation_error_deg": list(evaluation.rotation_error_deg),
                     "energy_cm2": list(evaluation.energy_cm2)})


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=float, default=0.15, help="fraction of the head's firings simulated")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--range-noise", type=float, default=0.005, help="range noise of the head [m]")
    parser.add_argument("--robust", default=None, choices=("none", "huber", "cauchy"),
                        help="weighting.robust (default: calibrate's default)")
    parser.add_argument("--moving-sigmas", default=None,
                        help="association.moving_sigmas, a number or none (default: calibrate's default)")
    parser.add_argument("--cases", nargs="*", default=["without", "with"], choices=("without", "with"),
                        help="the drive without traffic, with it, or both")
    parser.add_argument("--scenario", default="sim2_street", choices=("sim2_street", "city_loop"))
    parser.add_argument("--duration", type=float, default=10.0, help="seconds of city_loop's drive")
    parser.add_argument("--out", type=Path, default=RESULTS / "traffic.json")
    args = parser.parse_args()
    settings = {} if args.robust is None else {"weighting": {"robust": args.robust}}
    if args.moving_sigmas is not None:
        sigmas = None if args.moving_sigmas.lower() == "none" else float(args.moving_sigmas)
        settings["association"] = {"moving_sigmas": sigmas}
    cases = {}
    for traffic in [case == "with" for case in args.cases]:
        row = run_in_process(_case, traffic, args.size, args.seed, args.range_noise, settings, args.scenario,
                             args.duration)
        cases["with_traffic" if traffic else "without_traffic"] = row
    ratio = {name: cases["with_traffic"]["intrinsic_rms"][name] / cases["without_traffic"]["intrinsic_rms"][name]
             for name in TYPES} if len(cases) == 2 and all("refused" not in row for row in cases.values()) else {}
    figures = {"machine": platform.platform(), "processor": platform.processor(),
               "date": datetime.datetime.now().isoformat(timespec="seconds"),
               "scenario": args.scenario, "duration_s": args.duration if args.scenario == "city_loop" else None,
               "size": args.size, "seed": args.seed, "range_noise_m": args.range_noise, "settings": settings,
               **{name: _flat(row) for name, row in cases.items()},
               "rms_ratio_with_to_without": ratio}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    report(figures, args.out)


def _flat(row: dict) -> dict:
    """A case's figures one level deep (report prints a flat group)."""
    flat = {}
    for key, value in row.items():
        if isinstance(value, dict):
            flat.update({f"{key}.{k}": v for k, v in value.items()})
        elif isinstance(value, list):
            flat.update({f"{key}[{k}]": v for k, v in enumerate(value)})
        else:
            flat[key] = value
    return flat


if __name__ == "__main__":
    main()
