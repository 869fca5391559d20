"""What the benchmark scripts share: a stage run in its own process, and its peak memory."""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import platform
import resource
from pathlib import Path
from queue import Empty


def machine() -> dict:
    """The machine a benchmark ran on: its CPUs, Python and platform (the results' "machine")."""
    return {"cpus": os.cpu_count(), "python": platform.python_version(), "platform": platform.platform()}


def peak_gib() -> float:
    """Peak resident memory of this process [GiB] (ru_maxrss is in kB on Linux)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20


def run_in_process(target, *args) -> dict:
    """target(*args, queue) in a fresh spawned process (its own peak memory); what it put on the
    queue. Stops with the target's name if the process dies without answering (its traceback is
    printed above), instead of waiting for ever."""
    context = mp.get_context("spawn")
    queue = context.Queue()
    process = context.Process(target=target, args=(*args, queue))
    process.start()
    while True:
        try:
            result = queue.get(timeout=5)
            break
        except Empty:
            if not process.is_alive():
                raise SystemExit(f"{target.__name__}{args} failed (exit code {process.exitcode})") from None
    process.join()
    return result


def city_loop_arguments(description: str, minutes: list[float], size: float, result: str) -> argparse.Namespace:
    """The options of a benchmark on city_loop drives (city_loop_drive), with their defaults."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--minutes", type=float, nargs="+", default=minutes)
    parser.add_argument("--size", type=float, default=size, help="fraction of firings simulated")
    parser.add_argument("--max-points", type=int, default=4_000_000, help="returns calibrate uses (its default)")
    parser.add_argument("--seed", type=int, default=0, help="the calibration's seed (its random draws)")
    parser.add_argument("--result", default=result, help="file name in benchmarks/results/")
    parser.add_argument("--keep", help="folder where the simulated drives are kept and found again (default: a "
                                       "temporary folder, simulated each run)")
    return parser.parse_args()


def city_loop_drive(folder: str | Path, minutes: float, size: float) -> tuple[Path, float | None]:
    """city_loop driven for `minutes` at `size` (seed 0, 5 mm range noise), simulated straight to disk in
    folder/city_<minutes>min_size<size> unless it is there already: (its folder, the seconds simulating took, None
    when found)."""
    import time

    from graphcal.simulation.script import load_scenario_builder
    from graphcal.simulation.simulator import simulate_to

    drive = Path(folder) / f"city_{minutes:g}min_size{size:g}"
    if (drive / "recording.yaml").exists():
        return drive, None
    started = time.perf_counter()
    simulate_to(load_scenario_builder("city_loop")(duration_s=60.0 * minutes, size=size, seed=0, range_noise_m=0.005),
                drive, quiet=True)
    return drive, round(time.perf_counter() - started, 1)


def extrinsic_sigmas(sigma) -> dict | None:
    """{axis: 1-sigma in file units (deg, m)} of an Uncertainty's extrinsic row, None for a held axis; None when not
    estimated."""
    from graphcal.calibration.observability import EXTRINSIC_NAMES

    if sigma is None:
        return None
    return {axis: None if v != v else float(v) for axis, v in zip(EXTRINSIC_NAMES, sigma)}


def report(figures: dict, path: Path) -> None:
    """Print the figures (a dict value as a titled group) and write them to `path` as JSON, atomically."""
    from graphcal.common.atomic import atomic_path

    def show(items, indent=""):
        for key, value in items.items():
            if isinstance(value, dict) and all(not isinstance(v, dict) for v in value.values()) and indent == "":
                print(key)
                show(value, "  ")
            else:
                numeric = isinstance(value, (int, float)) and not isinstance(value, bool)
                text = (f"{value:,.3f}" if isinstance(value, float) else f"{value:,}") if numeric else value
                print(f"{indent}{key:>30}: {text}")

    show(figures)
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(figures, indent=2))
