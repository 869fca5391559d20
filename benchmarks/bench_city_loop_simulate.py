"""Benchmark: simulate city_loop for 30 s and 60 s, streamed to disk (simulate_to) and in memory (simulate).

simulate_to writes points.parquet a row group per second of firings: its peak memory should stay flat
as the drive gets longer, while simulate's grows with the returns it holds. Each run is in its own
process so its peak memory is its own. Prints the figures and writes
benchmarks/results/city_loop_simulate.json (with the machine and the date).
"""

from __future__ import annotations

import argparse
import datetime
import multiprocessing as mp
import platform
import tempfile
import time
from pathlib import Path

from common import peak_gib, report, run_in_process

RESULTS = Path(__file__).resolve().parent / "results"


def _run(mode: str, duration_s: float, size: float, out: str, queue) -> None:
    import pyarrow.parquet as pq

    from graphcal.simulation.script import load_scenario_builder
    from graphcal.simulation.simulator import simulate, simulate_to

    scenario = load_scenario_builder("city_loop")(duration_s=duration_s, size=size, seed=0)
    started = time.perf_counter()
    if mode == "streamed":
        simulate_to(scenario, out, quiet=True)
    else:
        simulate(scenario, quiet=True).save(out)
    seconds = time.perf_counter() - started
    metadata = pq.ParquetFile(Path(out) / "points.parquet").metadata
    queue.put({"returns": metadata.num_rows, "row_groups": metadata.num_row_groups,
               "seconds": round(seconds, 2), "peak_gib": round(peak_gib(), 3)})


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=float, default=0.25, help="fraction of firings (1 = full size)")
    parser.add_argument("--durations", type=float, nargs="+", default=[30.0, 60.0], help="drive lengths [s]")
    args = parser.parse_args()
    figures = {"benchmark": "city_loop_simulate", "machine": platform.platform(), "cpus": mp.cpu_count(),
               "python": platform.python_version(),
               "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"), "size": args.size}
    with tempfile.TemporaryDirectory() as tmp:
        for mode in ("streamed", "in_memory"):
            for duration_s in args.durations:
                out = str(Path(tmp) / f"{mode}_{duration_s:g}")
                figures[f"{mode}_{duration_s:g}s"] = run_in_process(_run, mode, duration_s, args.size, out)
    streamed = [figures[f"streamed_{d:g}s"]["peak_gib"] for d in args.durations]
    figures["streamed_peak_growth"] = round(streamed[-1] / streamed[0], 3)
    report(figures, RESULTS / "city_loop_simulate.json")


if __name__ == "__main__":
    main()
