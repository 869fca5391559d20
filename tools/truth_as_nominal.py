"""A copy of a simulated recording whose nominal model is its truth: a calibration started there must stay
within its sigmas (tests/test_foreign_from_truth.py, benchmarks/bench_foreign.py --from-truth)."""

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
