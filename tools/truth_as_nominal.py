"""A copy of a simulated recording whose nominal model is its truth: a calibration started there must stay
within its sigmas (tests/test_foreign_from_truth.py, benchmarks/bench_foreign.py --from-truth); or whose nominal
model's reference fibre is off the truth (bench_foreign.py --reference-error)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from graphcal.common.yamlfile import read_yaml, write_yaml
from graphcal.recording.intrinsics import load_offsets_csv, save_offsets_csv
from graphcal.recording.sensor import SensorModel


def truth_as_nominal(source: Path, target: Path) -> Path:
    """Copy the recording at `source` to `target` with the true offsets folded into sensor.yaml
    (SensorModel.with_offsets), the true extrinsic as extrinsic.yaml and zero offsets as the truth; returns
    `target`."""
    shutil.copytree(source, target)
    sensor = SensorModel.from_dict(read_yaml(target / "sensor.yaml"), target / "sensor.yaml")
    truth = load_offsets_csv(target / "truth" / "intrinsics.csv", sensor.n_fibres)
    write_yaml(target / "sensor.yaml", sensor.with_offsets(truth).to_dict())
    shutil.copy(target / "truth" / "extrinsic.yaml", target / "extrinsic.yaml")
    save_offsets_csv(target / "truth" / "intrinsics.csv", np.zeros_like(truth))
    return target


def reference_off(source: Path, target: Path, range_m: float, elevation_deg: float) -> Path:
    """Copy the recording at `source` to `target` with its nominal model's reference fibre off the truth by range_m
    [m] in range and elevation_deg [deg] in elevation (the truth is the nominal plus those: a factory model off on
    that fibre as on the others, which the calibration's gauge holds exact); the truth's offsets say so; returns
    `target`."""
    shutil.copytree(source, target)
    sensor = SensorModel.from_dict(read_yaml(target / "sensor.yaml"), target / "sensor.yaml")
    error = np.zeros((sensor.n_fibres, 4))
    error[sensor.reference_fibre] = [range_m, 0.0, np.radians(elevation_deg), 0.0]
    write_yaml(target / "sensor.yaml", sensor.with_offsets(-error).to_dict())
    truth = load_offsets_csv(target / "truth" / "intrinsics.csv", sensor.n_fibres)
    save_offsets_csv(target / "truth" / "intrinsics.csv", truth + error)
    return target
