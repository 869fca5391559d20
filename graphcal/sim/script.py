"""Command-line entry shared by the scenario scripts in scenarios/: simulate, then save."""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from pathlib import Path

from graphcal.sim.scenario import Scenario
from graphcal.sim.simulator import simulate


def run_scenario_script(build: Callable[..., Scenario], argv: list[str] | None = None) -> Path:
    """Parse --out/--size/--seed/--quiet, simulate build(size=, seed=) and write the recording."""
    name = build.__module__.rsplit(".", 1)[-1]
    parser = argparse.ArgumentParser(description=(build.__doc__ or name).strip().splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out") / name, help="recording directory to write")
    parser.add_argument("--size", type=float, default=1.0, help="fraction of the sensor's firings kept (0-1]")
    parser.add_argument("--seed", type=int, default=0, help="seed of every random draw")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)
    started = time.perf_counter()
    recording = simulate(build(size=args.size, seed=args.seed), quiet=args.quiet)
    recording.save(args.out)
    if not args.quiet:
        print(f"{len(recording.points):,} returns written to {args.out} in {time.perf_counter() - started:.1f} s")
    return args.out
