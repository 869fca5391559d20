"""Benchmark: how far the estimate spreads under range noise, against the shared-returns sigmas.

sim2_street without noise is simulated once; each draw adds fresh Gaussian range noise to every
return, makes the pairs on that noisy cloud at the true calibration (the pipeline's own association:
stand-ins, features, gates) and takes one Gauss-Newton step there. The RMS over the draws of that step
(per parameter type, eq. 4.6 units) is set against the RMS of the shared-returns sigmas
(graphcal/calibration/shared_returns.py) of each draw's pairs, as calibrate reports them: a ratio above
1 is variance the sandwich leaves out (docs/reference/math.md "Observability"). No outer loop and
no pair-draw luck of one run: the measurement for changes to the noisy-head association.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from common import peak_gib

from graphcal.common.atomic import atomic_path
from graphcal.simulation.starts import FAR_START_PRIORS

RESULTS = Path(__file__).resolve().parent / "results"
# eq. 4.6 units of (d_range, d_azimuth, d_elevation, h_z): cm, deg, deg, cm
TO_CM_DEG = np.array([100.0, np.degrees(1.0), np.degrees(1.0), 100.0])


def main() -> None:
    import graphcal
    from graphcal.calibration.config import ESTIMATES, CalibrationConfig
    from graphcal.calibration.priors import Priors
    from graphcal.calibration.problem import Problem
    from graphcal.calibration.returns import initial_estimate, prepare
    from graphcal.calibration.shared_returns import Linearised, shared_returns_covariance
    from graphcal.common.progress import progress
    from graphcal.simulation.script import load_scenario_builder

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=float, default=1.0, help="fraction of firings (1 = full size)")
    parser.add_argument("--max-points", type=int, default=1_500_000, help="returns used")
    parser.add_argument("--draws", type=int, default=8, help="noise draws")
    parser.add_argument("--seed", type=int, default=7, help="scenario seed (the scene and the pair draws)")
    parser.add_argument("--range-noise-m", type=float, default=0.01)
    parser.add_argument("--out", type=Path, default=RESULTS / "noise_spread.json")
    args = parser.parse_args()
    if args.draws < 1 or args.range_noise_m <= 0 or not 0 < args.size <= 1:
        parser.error(f"expected --draws >= 1, --range-noise-m > 0 and 0 < --size <= 1 (got {args.draws}, "
                     f"{args.range_noise_m}, {args.size})")
    started = time.perf_counter()
    recording = graphcal.simulate(load_scenario_builder("sim2_street")(size=args.size, seed=args.seed), quiet=True)
    noise_m = args.range_noise_m
    config = CalibrationConfig(mode="intrinsic", weighting={"sigma0_m": noise_m, "range_noise_m": noise_m},
                               seed=args.seed, max_points=args.max_points, priors=FAR_START_PRIORS)  # Table 4.1's truth
    clean = prepare(recording, config.trajectory.control_interval_s, config.max_points,
                    np.random.default_rng(config.seed), range_noise_m=noise_m)
    config = config.for_sensor(clean.static, np.nan)
    truth = replace(initial_estimate(recording, clean), offsets=recording.truth.intrinsics)
    problem = Problem(clean, config, ESTIMATES["intrinsic"], truth.extrinsic,
                      Priors.of(config, clean.sensor.n_fibres, len(clean.control_times_s)))

    rng = np.random.default_rng(args.seed)
    steps, variances = [], []
    for _ in progress(range(args.draws), "noise draws"):
        noisy = replace(clean, range_m=clean.range_m + rng.normal(0.0, noise_m, len(clean.range_m)))
        on_noisy = replace(problem, full=noisy, data=noisy, cache=None)
        pairs = on_noisy.associate(truth)
        blocks = on_noisy.blocks(truth, pairs)
        graph, values = on_noisy.graph(truth, pairs, damped=False, blocks=blocks)
        keys = list(values.keys())
        step = graph.linearize(values).optimize()
        steps.append([step.at(key) for key in keys])
        covariance = shared_returns_covariance(Linearised.of(graph, values, blocks, len(pairs)), pairs, noisy, truth, noise_m)
        variances.append([np.diag(covariance.marginalCovariance(key)) for key in keys])
    spread = np.sqrt((np.array(steps) ** 2).mean(axis=(0, 1))) * TO_CM_DEG
    sigma = np.sqrt(np.array(variances).mean(axis=(0, 1))) * TO_CM_DEG
    figures = {"machine": platform.platform(), "size": args.size, "seed": args.seed, "draws": args.draws,
               "returns": len(recording.points), "max_points": args.max_points, "range_noise_m": noise_m,
               "rms_step_cm_deg_deg_cm": spread.tolist(), "rms_sigma_shared_cm_deg_deg_cm": sigma.tolist(),
               "ratio": (spread / sigma).tolist(), "seconds": time.perf_counter() - started, "peak_gib": peak_gib()}
    print(f"{args.draws} draws, {figures['seconds']:.0f} s, peak {figures['peak_gib']:.2f} GiB\n"
          f"RMS step (cm, deg, deg, cm): {spread.round(5)}\nRMS shared-returns sigma: {sigma.round(5)}\n"
          f"ratio: {(spread / sigma).round(3)}")
    with atomic_path(args.out) as tmp:
        tmp.write_text(json.dumps(figures, indent=2))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
