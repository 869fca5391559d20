"""Calibration on recordings graphcal's simulator did not make (tools/foreign_sim: its own scene, firing
pattern, vehicle dynamics and INS noise), checked against their truth.

A level head in a box street with cars and poles, 1 cm range noise, a 5 mm / 0.005 deg white INS: the
ordinary mapping car whose calibration once slid into the fibres' collapse. The figures of every scene
family at larger sizes are benchmarks/bench_foreign.py's."""

import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

import graphcal
from graphcal.calibration.evaluate import scorecard
from graphcal.recording.intrinsics import load_offsets_csv, save_offsets_csv
from graphcal.recording.sensor import SensorModel
from graphcal.common.yamlfile import read_yaml, write_yaml

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tools.foreign_sim import simulate  # noqa: E402


@pytest.fixture(scope="module")
def box_street(tmp_path_factory) -> Path:
    return simulate("box_street", tmp_path_factory.mktemp("foreign") / "box", duration_s=15.0, size=0.03, seed=2,
                    mount="level")


def _truth_as_nominal(source: Path, target: Path) -> Path:
    """A copy of the recording whose nominal model is its truth (offsets folded into sensor.yaml, the true
    extrinsic as extrinsic.yaml) and whose truth is then zero offsets."""
    shutil.copytree(source, target)
    sensor = SensorModel.from_dict(read_yaml(target / "sensor.yaml"))
    truth = load_offsets_csv(target / "truth" / "intrinsics.csv", sensor.n_fibres)
    write_yaml(target / "sensor.yaml", sensor.with_offsets(truth).to_dict())
    shutil.copy(target / "truth" / "extrinsic.yaml", target / "extrinsic.yaml")
    save_offsets_csv(target / "truth" / "intrinsics.csv", np.zeros_like(truth))
    return target


def test_a_level_head_in_a_box_street_converges_without_collapse(box_street):
    """From the factory's nominal model (3 cm, 0.3 deg off) with calibrate's defaults: no collapse, a few
    parameters named, the others close to the truth and mostly within 3 of their sigmas, the extrinsic
    found (the drive turns at the junction)."""
    recording = graphcal.Recording.load(box_street)
    result = graphcal.calibrate(recording, quiet=True)
    assert result.config.mode == "joint"  # the drive never comes back: no trajectory corrections
    card = scorecard(result, recording)
    evaluation = graphcal.evaluate(result, recording)
    assert card.named_fraction <= 0.25, result.unobservable
    # the goal is 90 %; measured 83 % here (size 0.03), 97 % at size 0.1 (benchmarks/bench_foreign.py); a slide
    # into the collapse left a third
    assert card.within_3_sigma >= 0.8, card
    assert card.rms_observable[0] < 0.5 and card.rms_observable[1] < 0.02, card  # cm, deg
    assert card.rms_observable[2] < 0.05 and card.rms_observable[3] < 1.0, card  # deg, cm
    assert np.all(evaluation.intrinsic_rms_after[:3] < 0.5 * evaluation.intrinsic_rms_before[:3]), evaluation.table()
    assert evaluation.rotation_error_deg[1] < 0.05 and evaluation.lever_arm_error_m[1] < 0.02, evaluation.table()
    assert evaluation.cloud_after_gauge_free.mean < 0.8 * evaluation.cloud_before.mean, evaluation.table()


def test_started_at_the_truth_the_fit_stays_within_its_sigmas(box_street, tmp_path):
    """Nominal model = truth: the paired energy's minimum must be the truth, so the fit stays within its
    reported sigmas and names what it cannot see instead of sliding along it."""
    recording = graphcal.Recording.load(_truth_as_nominal(box_street, tmp_path / "at_truth"))
    result = graphcal.calibrate(recording, quiet=True)
    card = scorecard(result, recording)
    assert card.named_fraction <= 0.25, result.unobservable
    assert card.within_3_sigma >= 0.85, card  # measured 87 % (size 0.03), 97 % at size 0.1; the goal is 90 %
    assert card.rms_observable[0] < 0.5 and card.rms_observable[3] < 0.5, card
    assert np.abs(result.calibration.estimate.offsets[:, 2]).max() < np.radians(0.1)  # no elevation slid
