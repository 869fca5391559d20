"""Flagship demo: simulate sim6_turn, read it back through the recording contract, and measure
how far the cloud georeferenced with the nominal model lies from the truth."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from graphcal.georeference import georeference_batches
from graphcal.metrics import DistanceStats, cloud_to_cloud
from graphcal.recording import Recording
from graphcal.sim.script import load_scenario_builder
from graphcal.sim.simulator import simulate


def run_demo(out: Path, size: float = 1.0, quiet: bool = False) -> dict:
    """Returns the figures it prints: returns, times [s], nominal-vs-truth distances [m]."""
    started = time.perf_counter()
    recording = simulate(load_scenario_builder("sim6_turn")(size=size, seed=0), quiet=quiet)
    recording.save(out)
    simulated = time.perf_counter()
    recording = Recording.load(out)
    loaded = time.perf_counter()
    nominal = np.concatenate(list(georeference_batches(recording.points, recording.sensor, recording.extrinsic,
                                                       recording.world.poses)))
    truth = recording.truth.world_points()
    per_point = DistanceStats.of(np.linalg.norm(nominal - truth, axis=1))
    c2c = DistanceStats.of(cloud_to_cloud(nominal, truth))
    figures = {"returns": len(recording.points), "simulate_s": simulated - started, "load_s": loaded - simulated,
               "per_point_error": per_point, "cloud_to_cloud": c2c}
    if not quiet:
        print(f"simulated {len(recording.points):,} returns of sim6_turn in {simulated - started:.1f} s -> {out}")
        print(f"loaded and validated in {loaded - simulated:.1f} s")
        print(f"nominal model vs truth, per return:  {per_point}")
        print(f"nominal model vs truth, cloud-to-cloud: {c2c}")
        print(f"inspect: graphcal info {out}")
    return figures
