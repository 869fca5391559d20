"""Benchmark: calibrate recordings graphcal's simulator did not make (tools/foreign_sim), against truth.

For each scene family (box_street, suburb, open_road, relief_street) and mounting (level, tilted), a drive of an
HDL-32E-class head with 1 cm range noise, an INS with 5 mm / 0.005 deg white noise, true intrinsic offsets within
3 cm and 0.3 deg (the factory's nominal model) and an extrinsic within 5 cm and 0.5 deg is simulated by the
independent simulator and calibrated with graphcal.calibrate's defaults. Figures per case
(graphcal.calibration.evaluate.scorecard): RMS error over the intrinsic parameters not named unobservable (cm,
deg, deg, cm), the fraction of their errors within 3 reported sigmas, the fraction named unobservable; the same
over the determined ones (named neither unobservable nor imprecise: graphcal.calibration.accuracy) and the
fraction named imprecise; how each phase stopped and the verdict, the extrinsic errors, J, seconds and peak
memory. --from-truth starts each calibration at the truth (sensor.yaml and extrinsic.yaml set to the true values,
the truth then zero offsets): the fit must stay within its sigmas. --far draws the truth within the widest errors
a factory model is expected to have (5 cm and 0.5 deg per fibre, the extrinsic within 10 cm and 1 deg).
--reference-error puts the nominal model's reference fibre off the truth in range and elevation (the simulator
draws it exact; a real head's factory model is off on it as on the others, while the calibration's gauge holds
it). --range-noise-m and --ins-noise set the noises (to tell which one an error comes from); --fine-pairs the fine
phase's pairs per fibre pair. Writes
benchmarks/results/foreign.json (foreign_from_truth.json, foreign_far.json; or --out).
"""

from __future__ import annotations

import argparse
import datetime
import json
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from common import extrinsic_sigmas, peak_gib, run_in_process

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tools.foreign_sim, from the checkout

from graphcal.common.atomic import atomic_path
from tools.foreign_sim import WIDEST_FACTORY_ERRORS

RESULTS = Path(__file__).resolve().parent / "results"
FAMILIES = ("box_street", "suburb", "open_road", "relief_street")
MOUNTS = ("level", "tilted")


def _case(family: str, mount: str, size: float, duration_s: float, seed: int, from_truth: bool, far: bool,
          settings: dict, reference_error: tuple[float, float] | None, noise: dict, queue) -> None:
    import graphcal
    from graphcal.calibration.evaluate import scorecard
    from graphcal.common.errors import CalibrationError
    from tools.foreign_sim import simulate
    from tools.truth_as_nominal import reference_off, truth_as_nominal

    with tempfile.TemporaryDirectory() as folder:
        directory = simulate(family, Path(folder) / "rec", duration_s=duration_s, size=size, seed=seed, mount=mount,
                             **noise, **(WIDEST_FACTORY_ERRORS if far else {}))
        if from_truth:
            directory = truth_as_nominal(Path(directory), Path(folder) / "at_truth")
        if reference_error is not None:
            directory = reference_off(Path(directory), Path(folder) / "reference_off", *reference_error)
        recording = graphcal.Recording.load(directory)
        row = {"family": family, "mount": mount, "seed": seed, "from_truth": from_truth, "far": far,
               "reference_error": reference_error, "returns": len(recording.points)}
        started = time.perf_counter()
        try:
            result = graphcal.calibrate(recording, graphcal.CalibrationConfig(**settings, seed=seed), quiet=True)
        except CalibrationError as error:
            queue.put(row | {"calibrate_s": time.perf_counter() - started, "refused": str(error),
                             "peak_gib": peak_gib()})
            return
        seconds = time.perf_counter() - started
        evaluation = graphcal.evaluate(result, recording)
        card = scorecard(result, recording)
    queue.put(row | {"mode": result.config.mode, "calibrate_s": seconds, "peak_gib": peak_gib(),
                     "timings_s": {stage: round(t, 2) for stage, t in result.timings_s.items()},
                     "outer_iterations": len(result.history), **card.to_dict(),
                     "stops": [row["stop"] for row in result.history if row["stop"]], "verdict": result.verdict,
                     "unobservable": list(result.unobservable),
                     "extrinsic_sigma": extrinsic_sigmas(result.sigmas.extrinsic),
                     "extrinsic_imprecise": [name for name in result.calibration.imprecise
                                             if name.startswith("extrinsic.")],
                     "lever_arm_error_m": list(evaluation.lever_arm_error_m),
                     "lever_arm_error_all_axes_m": [_lever_arm_error(t, recording) for t in
                                                    (recording.extrinsic.lever_arm_m,
                                                     result.calibration.estimate.extrinsic.translation())],
                     "c2c_mean_cm": [evaluation.cloud_before.mean * 100, evaluation.cloud_after.mean * 100],
                     "rotation_error_deg": list(evaluation.rotation_error_deg),
                     "energy_cm2": list(evaluation.energy_cm2),
                     "c2c_mean_gauge_free_cm": evaluation.cloud_after_gauge_free.mean * 100,
                     "table": evaluation.table()})


def _lever_arm_error(lever_arm_m, recording) -> float:
    """|lever arm - truth| [m] over the three axes, a held one's (its nominal's error) included."""
    return float(np.linalg.norm(np.asarray(lever_arm_m) - np.asarray(recording.truth.extrinsic.lever_arm_m)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--families", nargs="*", default=list(FAMILIES), choices=FAMILIES)
    parser.add_argument("--mounts", nargs="*", default=list(MOUNTS), choices=MOUNTS)
    parser.add_argument("--size", type=float, default=0.1, help="fraction of the head's firings simulated")
    parser.add_argument("--duration", type=float, default=15.0, help="seconds of drive")
    parser.add_argument("--seeds", type=int, default=1)
    parser.add_argument("--from-truth", action="store_true", help="start each calibration at the truth")
    parser.add_argument("--far", action="store_true", help="true errors within 5 cm, 0.5 deg (extrinsic 10 cm, 1 deg)")
    parser.add_argument("--mode", default=None, help="calibrate's mode (default: its default)")
    parser.add_argument("--reference-error", type=float, nargs=2, metavar=("RANGE_M", "ELEVATION_DEG"),
                        help="the nominal model's reference fibre off the truth by these (the gauge holds it exact)")
    parser.add_argument("--reference-fibre", choices=("fixed", "range_elevation"), default=None,
                        help="priors.reference_fibre (default: calibrate's)")
    parser.add_argument("--fine-pairs", type=int, default=None,
                        help="association.fine.pairs_per_fibre_pair (default: calibrate's)")
    parser.add_argument("--range-noise-m", type=float, default=0.01, help="the head's range noise [m]")
    parser.add_argument("--ins-noise", type=float, nargs=2, default=(0.005, 0.005), metavar=("M", "DEG"),
                        help="the INS's white noise per sample: position [m] and attitude [deg]")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    if args.range_noise_m < 0 or min(args.ins_noise) < 0:
        parser.error(f"expected --range-noise-m and --ins-noise >= 0 (got {args.range_noise_m}, {args.ins_noise})")
    noise = {"range_noise_m": args.range_noise_m, "ins_noise_m": args.ins_noise[0], "ins_noise_deg": args.ins_noise[1]}
    settings = {} if args.mode is None else {"mode": args.mode}
    if args.reference_fibre is not None:
        settings["priors"] = {"reference_fibre": args.reference_fibre}
    if args.fine_pairs is not None:
        settings["association"] = {"fine": {"pairs_per_fibre_pair": args.fine_pairs}}
    rows = []
    for family in args.families:
        for mount in args.mounts:
            for seed in range(args.seeds):
                row = run_in_process(_case, family, mount, args.size, args.duration, seed, args.from_truth, args.far,
                                     settings, args.reference_error, noise)
                rows.append(row)
                if "refused" in row:
                    print(f"{family}/{mount} seed {seed}: refused ({row['calibrate_s']:.0f} s): {row['refused']}",
                          flush=True)
                    continue
                rms = ", ".join(f"{k} {v:.4g}" for k, v in row["rms_observable"].items())
                determined = ", ".join(f"{v:.4g}" for v in row["rms_determined"].values())
                print(f"{family}/{mount} seed {seed}: {row['returns']:,} returns, {row['calibrate_s']:.0f} s, "
                      f"{row['peak_gib']:.2f} GiB; RMS over the observable: {rms}; within 3 sigma "
                      f"{row['within_3_sigma']:.0%}; named {row['named_fraction']:.0%}; over the determined "
                      f"{determined}, within 3 sigma {row['within_3_sigma_determined']:.0%}, imprecise "
                      f"{row['imprecise_fraction']:.0%}, extrinsic imprecise "
                      f"{', '.join(row['extrinsic_imprecise']) or 'none'}; lever arm (all axes) "
                      f"{row['lever_arm_error_all_axes_m'][0] * 100:.2f} -> "
                      f"{row['lever_arm_error_all_axes_m'][1] * 100:.2f} cm, "
                      f"rotation {row['rotation_error_deg'][1]:.4f} deg; "
                      f"J {row['energy_cm2'][0]:.3g} -> {row['energy_cm2'][1]:.3g} cm2", flush=True)
    out = args.out or RESULTS / ("foreign_from_truth.json" if args.from_truth else "foreign_far.json" if args.far
                                 else "foreign.json")
    out.parent.mkdir(parents=True, exist_ok=True)
    bounds = WIDEST_FACTORY_ERRORS if args.far else "the simulator's defaults"
    with atomic_path(out) as tmp:
        tmp.write_text(json.dumps({"machine": platform.platform(), "processor": platform.processor(),
                                   "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
                                   "size": args.size, "duration_s": args.duration, "settings": settings,
                                   "true_error_bounds": bounds, "reference_error": args.reference_error, "noise": noise,
                                   "cases": rows}, indent=2))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
