"""Benchmark: the per-tile stage of a calibration (features and pairs of one outer iteration,
graphcal.calibration.tiles) in one process, and on Dask LocalClusters of one and two worker processes.

A recording of the independent simulator (tools/foreign_sim, relief_street, tilted mount) is calibrated's
input: the returns a calibration uses (max_points), placed at the nominal calibration. The configurations: in
process; LocalClusters of one and two workers (`--dask local:N`: a worker's libraries, open3d's thread pool
among them, use every core, so one worker already keeps both of this machine's cores busy in the features'
neighbour searches); and clusters of one and two single-core workers (`--dask tcp://...`: a scheduler and
`dask worker` processes started here, each confined to one core before it loads anything, as a worker per core
of a cluster is). Each configuration runs
the stage `repeats` times (the first, which starts the workers and ships the code, is reported apart). The
time spent in the task map's calls (the tiles' jobs, shipped out and gathered back) is timed apart from the
stage's driver side (splitting the cloud into tiles, merging their pairs); in process, each tile's job is timed
too: their sum and the largest are the part a cluster can spread (two workers take at least the larger of half
the sum and the largest job). Prints the figures and writes benchmarks/results/tiles.json. The speed-up target:
two workers at least 1.7x one on the per-tile work. --configurations runs some of them only (e.g. the two
single-core ones, to compare two commits run one after the other), --out writes elsewhere.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path

from common import machine, peak_gib, report

RESULTS = Path(__file__).resolve().parent / "results"
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tools.foreign_sim, from the checkout


class Timed:
    """A graphcal.common.cluster TaskMap that times each call [s] (calls) and, with per_job (in process), each
    job [s] (jobs)."""

    def __init__(self, task_map, per_job: bool):
        self.task_map, self.per_job, self.calls, self.jobs = task_map, per_job, [], []

    @property
    def workers(self) -> int:
        return self.task_map.workers

    def __call__(self, function, jobs, costs=None):
        started = time.perf_counter()
        if self.per_job:
            out = []
            for job in jobs:
                begun = time.perf_counter()
                out.append(function(job))
                self.jobs.append(time.perf_counter() - begun)
        else:
            out = self.task_map(function, jobs, costs)
        self.calls.append(time.perf_counter() - started)
        return out


# (name, --dask address, single-core workers started here for it: their scheduler is the address)
CONFIGURATIONS = (("in process", None, 0), ("local:1", "local:1", 0), ("local:2", "local:2", 0),
                  ("one single-core worker", None, 1), ("two single-core workers", None, 2))


@contextmanager
def single_core_cluster(workers: int, folder: Path) -> Iterator[str]:
    """A scheduler and `workers` dask worker processes of one thread, the i-th confined to core i (from its
    start, so that its libraries' thread pools see one core); the scheduler's address, once they are up."""
    dask = Path(sys.executable).with_name("dask")
    file = folder / f"scheduler-{workers}.json"
    processes = [subprocess.Popen([dask, "scheduler", "--port", "0", "--dashboard-address", ":0", "--scheduler-file",
                                   file], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        while not file.exists():
            if processes[0].poll() is not None:
                raise SystemExit(f"dask scheduler exited with code {processes[0].returncode}")
            time.sleep(0.2)
        address = json.loads(file.read_text())["address"]
        cores = sorted(os.sched_getaffinity(0))
        for core in cores[:workers]:
            processes.append(subprocess.Popen(
                [dask, "worker", address, "--nthreads", "1", "--no-nanny", "--no-dashboard"],
                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                preexec_fn=lambda core=core: os.sched_setaffinity(0, {core})))
        wait_for_workers(address, workers)
        yield address
    finally:
        for process in reversed(processes):
            process.terminate()
            process.wait()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--duration", type=float, default=15.0)
    parser.add_argument("--size", type=float, default=0.3)
    parser.add_argument("--max-points", type=int, default=1_000_000)
    parser.add_argument("--tile-m", type=float, default=50.0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--configurations", nargs="*", default=[name for name, *_ in CONFIGURATIONS],
                        choices=[name for name, *_ in CONFIGURATIONS], help="where the tiles run (default: everywhere)")
    parser.add_argument("--out", type=Path, default=RESULTS / "tiles.json")
    args = parser.parse_args()

    import numpy as np

    from graphcal.calibration.calibrate import CalibrationPipeline
    from graphcal.calibration.config import CalibrationConfig
    from graphcal.common.cluster import open_task_map
    from graphcal.recording.directory import Recording
    from tools.foreign_sim import simulate

    figures = {"machine": machine(),
               "date": datetime.date.today().isoformat(),
               "arguments": {k: v for k, v in vars(args).items() if k != "out"}}
    with tempfile.TemporaryDirectory() as folder:
        simulate("relief_street", Path(folder) / "r", duration_s=args.duration, size=args.size, seed=2, mount="tilted")
        recording = Recording.load(Path(folder) / "r")
        config = CalibrationConfig(mode="joint", max_points=args.max_points, association={"tile_m": args.tile_m})
        figures["returns"] = len(recording.points)
        for name, address, single_core_workers in CONFIGURATIONS:
            if name not in args.configurations:
                continue
            with ExitStack() as stack:
                if single_core_workers:
                    address = stack.enter_context(single_core_cluster(single_core_workers, Path(folder)))
                task_map = stack.enter_context(open_task_map(address))
                timed = Timed(task_map, per_job=address is None)
                pipeline = CalibrationPipeline(recording, config, True, timed)
                problem = pipeline.problem
                points = problem.points(pipeline.estimate)
                seconds, mapped = [], []
                for _ in range(args.repeats):
                    timed.calls.clear()
                    started = time.perf_counter()
                    features = problem.tiling.features(points, problem.settings.features)
                    pairs = problem.association().pairs(points, problem.data.fibre, features,
                                                        problem.gates.gate_start_m, problem.sight(pipeline.estimate))
                    seconds.append(time.perf_counter() - started)
                    mapped.append(sum(timed.calls))
                figures[name] = {
                    "tiles": len(problem.tiling.tiles(points)), "returns used": len(points), "pairs": len(pairs),
                    "first s": round(seconds[0], 2), "then s (median)": round(float(np.median(seconds[1:])), 2),
                    "per-tile work s (median)": round(float(np.median(mapped[1:])), 2)}
                if address is None:  # the jobs of one repeat: features then pairs, one of each a tile
                    jobs = np.array(timed.jobs[-2 * len(problem.tiling.tiles(points)):])
                    figures["in process"] |= {"tile jobs s (sum)": round(float(jobs.sum()), 2),
                                              "largest tile job s": round(float(jobs.max()), 2)}
        for kind, one, two in (("LocalCluster", "local:1", "local:2"),
                               ("single-core workers", "one single-core worker", "two single-core workers")):
            if one not in figures or two not in figures:
                continue
            figures[f"speed-up, two workers over one ({kind})"] = round(
                figures[one]["then s (median)"] / figures[two]["then s (median)"], 2)
            figures[f"speed-up of the per-tile work, two workers over one ({kind})"] = round(
                figures[one]["per-tile work s (median)"] / figures[two]["per-tile work s (median)"], 2)
        figures["peak GiB (driver)"] = round(peak_gib(), 2)
    args.out.parent.mkdir(exist_ok=True)
    report(figures, args.out)


def wait_for_workers(address: str, workers: int) -> None:
    """Until the scheduler at address has its workers."""
    from dask.distributed import Client

    with Client(address, timeout="30s") as client:
        client.wait_for_workers(workers, timeout=60)


if __name__ == "__main__":
    main()
