"""Benchmark: simulate sim6_turn at full size (about 4 M returns), save it, load it back.

Targets (issue 2): simulate <= 30 s and <= 3 GiB peak; load (validate every return and read
every column) <= 3 s. Each stage runs in its own process so its peak memory is its own.
Prints the figures and writes benchmarks/results/simulate.json.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import platform
import tempfile
import time
from pathlib import Path

from common import peak_gib, report, run_in_process

RESULTS = Path(__file__).resolve().parent / "results"


def _simulate(out: str, size: float, queue) -> None:
    from graphcal.simulation.script import load_scenario_builder
    from graphcal.simulation.simulator import simulate

    started = time.perf_counter()
    recording = simulate(load_scenario_builder("sim6_turn")(size=size, seed=0), quiet=True)
    simulated = time.perf_counter()
    recording.save(out)
    queue.put({"returns": len(recording.points), "simulate_s": simulated - started,
               "save_s": time.perf_counter() - simulated, "simulate_peak_gib": peak_gib()})


def _load(out: str, queue) -> None:
    from graphcal.recording.directory import Recording

    started = time.perf_counter()
    recording = Recording.load(out)
    columns = recording.points.read()
    queue.put({"load_s": time.perf_counter() - started, "load_peak_gib": peak_gib(),
               "loaded_returns": len(columns["time"])})


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=float, default=1.0, help="fraction of firings (1 = full size)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        out = str(Path(tmp) / "sim6_turn")
        figures = {"benchmark": "simulate_sim6_turn", "size": args.size, "cpus": mp.cpu_count(),
                   "python": platform.python_version()}
        figures.update(run_in_process(_simulate, out, args.size))
        figures.update(run_in_process(_load, out))
    figures["targets"] = {"simulate_s": 30.0, "simulate_peak_gib": 3.0, "load_s": 3.0}
    figures["met"] = all(figures[k] <= v for k, v in figures["targets"].items())
    report(figures, RESULTS / "simulate.json")


if __name__ == "__main__":
    main()
