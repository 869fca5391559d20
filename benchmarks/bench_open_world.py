"""Benchmark: the open-world mismatch finder (graphcal.diagnose(..., open_world=True)) on physics it was never
told about (scenarios/unlisted.py), and on the clean recording.

For each case (each in its own process, so each has its own peak memory): the first finding, whether it is
`discovered` on the unlisted effect's channel and regressor, the shape error of its curve against the true
curve (_shape_error: the error less a constant, and for an elevation curve against the azimuth less its
once-a-turn part, which the boresight takes, fitted and weighted by the curve's band; RMS error over the
truth's RMS), the error in units of the curve's own 1-sigma band point by point (about 1 when the band
covers the truth), held-out J before and after, the seconds, and the
strongest discrepancy of the effect's own channel and regressor (its statistic, significance and held-out J)
whether it was reported or not. Prints the figures and writes benchmarks/results/open_world.json.
"""

from __future__ import annotations

import argparse
import datetime
import platform
import time
from pathlib import Path

from common import peak_gib, report, run_in_process

RESULTS = Path(__file__).resolve().parent / "results"


def _shape_error(finding: dict, unlisted) -> tuple[float, float]:
    """The curve's error against the truth once the parts the fit cannot see are removed from it (a constant, and
    for an elevation curve against the azimuth its once-a-turn part), fitted with each point weighted by its band
    (1/sigma^2: the curve's points are seen unequally, a fibre that sees only the road hardly at all): the error's
    RMS over the truth's, both so weighted, and the RMS of the error in units of each point's band (about 1 when
    the band covers the truth)."""
    import numpy as np

    x, y = np.asarray(finding["curve"]["x"], dtype=float), np.asarray(finding["curve"]["y"], dtype=float)
    sigma = np.asarray(finding["curve"]["sigma"], dtype=float)
    truth, weight = unlisted.curve(x), 1.0 / sigma ** 2
    columns = [np.ones_like(x)]
    if finding["channel"] == "elevation" and finding["regressor"] == "azimuth":
        columns += [np.sin(np.radians(x)), np.cos(np.radians(x))]
    A = np.column_stack(columns) / sigma[:, None]

    def unseen_removed(v):
        return v - np.column_stack(columns) @ np.linalg.lstsq(A, v / sigma, rcond=None)[0]

    error, truth = unseen_removed(y - truth), unseen_removed(truth)
    shape = np.sqrt(np.sum(weight * error ** 2) / np.sum(weight * truth ** 2))
    return float(shape), float(np.sqrt(np.mean((error / sigma) ** 2)))


def _case(effect: str | None, size: float, max_points: int, queue) -> None:
    import graphcal
    from graphcal.calibration.config import CalibrationConfig
    from graphcal.simulation.script import load_scenario_builder

    build = load_scenario_builder("unlisted")
    unlisted = build.__globals__["UNLISTED"]
    recording = graphcal.simulate(build(size=size, seed=0, effect=effect), quiet=True)
    config = CalibrationConfig(mode="joint", max_points=max_points, stopping={
        "max_outer_iterations": 3, "tolerance_m": 1e-3, "refuse_unconverged": False})
    started = time.perf_counter()
    diagnosis = graphcal.diagnose(recording, config, max_effects=2, refit_iterations=2, quiet=True, open_world=True)
    out = {"returns": len(recording.points), "seconds": round(time.perf_counter() - started, 1),
           "peak_gib": round(peak_gib(), 2), "findings": [f["effect"] if f["effect"] != "discovered" else
                                                          f"discovered {f['channel']} x {f['regressor']}"
                                                          for f in diagnosis.findings]}
    if effect is not None:
        truth = unlisted[effect]
        first = diagnosis.findings[0] if diagnosis.findings else None
        out["right_first"] = bool(first and first["effect"] == "discovered"
                                  and (first["channel"], first["regressor"]) == (truth.channel, truth.regressor))
        if out["right_first"]:
            shape, in_band = _shape_error(first, truth)
            out["shape_error"], out["shape_error_in_band_sigmas"] = round(shape, 3), round(in_band, 2)
            out["held_out_cm2"] = [round(first["energy_cm2"]["held_out_before"], 4),
                                   round(first["energy_cm2"]["held_out_after"], 4)]
        own = [c for c in diagnosis.candidates if c["effect"].startswith(f"{truth.channel}~{truth.regressor}/")]
        if own:
            out["own_discrepancy"] = {"statistic": round(own[0]["statistic"], 1), "dof": own[0]["dof"],
                                      "significant": own[0]["significant"], "concealment_r2":
                                      round(own[0]["concealment_r2"], 3),
                                      "held_out_cm2": [round(v, 4) for v in own[0]["held_out_cm2"]]}
    queue.put(out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--size", type=float, default=0.1)
    parser.add_argument("--max-points", type=int, default=300_000)
    parser.add_argument("--cases", nargs="+", default=["clean", "range_walk", "thermal_range_drift", "head_wobble",
                                                       "firing_delay"])
    parser.add_argument("--out", type=Path, default=RESULTS / "open_world.json")
    args = parser.parse_args()
    figures = {"machine": {"platform": platform.platform(), "processor": platform.machine()},
               "date": datetime.date.today().isoformat(), "size": args.size, "max_points": args.max_points}
    for case in args.cases:
        figures[case] = run_in_process(_case, None if case == "clean" else case, args.size, args.max_points)
    report(figures, args.out)


if __name__ == "__main__":
    main()
