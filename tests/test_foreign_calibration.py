"""Calibration on recordings graphcal's simulator did not make (tools/foreign_sim: its own scene, firing
pattern, vehicle dynamics and INS noise), checked against their truth.

A level head in a box street with cars and poles, 1 cm range noise, a 5 mm / 0.005 deg white INS: the
ordinary mapping car whose calibration once slid into the fibres' collapse. The figures of every scene
family at larger sizes are benchmarks/bench_foreign.py's; the same street with the simulator's default errors,
started at its truth: test_foreign_from_truth.py (15 s of the drive; here 10 s from the widest errors)."""


import numpy as np
import pytest

import graphcal
from conftest import level_box_street
from graphcal.calibration.checkpoint import Checkpoint
from graphcal.calibration.config import CalibrationConfig
from graphcal.calibration.evaluate import scorecard
from graphcal.common.errors import ConfigError
from tools.foreign_sim import WIDEST_FACTORY_ERRORS


@pytest.fixture(scope="module")
def foreign_box_street(tmp_path_factory):
    """The widest errors a factory model is expected to have: the true offsets within 5 cm and 0.5 deg of the
    nominal model per fibre, the extrinsic within 10 cm and 1 deg."""
    return level_box_street(tmp_path_factory.mktemp("foreign") / "box", 10.0, **WIDEST_FACTORY_ERRORS)


@pytest.fixture(scope="module")
def calibrated(foreign_box_street):
    """The recording and its calibration with calibrate's defaults."""
    recording = graphcal.Recording.load(foreign_box_street)
    return recording, graphcal.calibrate(recording, quiet=True)


def test_a_level_head_in_a_box_street_converges_without_collapse(calibrated):
    """From the factory's nominal model (5 cm, 0.5 deg off) with calibrate's defaults: no collapse, a few
    parameters named, the others close to the truth and mostly within 3 of their sigmas, the extrinsic
    found (the drive turns at the junction)."""
    recording, result = calibrated
    assert result.config.mode == "joint"  # the drive never comes back: no trajectory corrections
    card = scorecard(result, recording)
    evaluation = graphcal.evaluate(result, recording)
    assert card.named_fraction <= 0.25, result.unobservable
    # the goal is 90 % (benchmarks/results/foreign.json has it at size 0.1); this small recording is held to 80 %;
    # a slide into the collapse left a third
    assert card.within_3_sigma >= 0.8, card
    assert card.rms_observable[0] < 0.5 and card.rms_observable[1] < 0.02, card  # cm, deg
    # measured 0.026 deg and 0.21 cm, every error within 3 sigmas: on this small recording the sigmas of the lowest
    # and the upward fibres' elevations are 0.02-0.06 deg (0.014 deg with the simulator's default errors)
    assert card.rms_observable[2] < 0.03 and card.rms_observable[3] < 0.3, card  # deg, cm
    assert np.all(evaluation.intrinsic_rms_after[:3] < 0.5 * evaluation.intrinsic_rms_before[:3]), evaluation.table()
    # the lever arm's z is seen only through the roll in the turn: 1.7 cm off on these 10 s, the rotation 0.022 deg
    assert evaluation.rotation_error_deg[1] < 0.05 and evaluation.lever_arm_error_m[1] < 0.025, evaluation.table()
    assert evaluation.cloud_after_gauge_free.mean < 0.8 * evaluation.cloud_before.mean, evaluation.table()


@pytest.mark.slow  # 90-130 s; resuming once: tests/test_runs.py
def test_a_calibration_interrupted_twice_resumes_to_the_uninterrupted_result(calibrated, tmp_path, monkeypatch):
    """Stopped in the coarse phase, then again in the fine one (as a SIGKILL would: the checkpoint as last
    saved), each time resumed from the checkpoint: the same outer iterations, the same estimate."""
    recording, whole = calibrated
    path, save, saves = tmp_path / "checkpoint.npz", Checkpoint.save, []

    def save_then_stop_in(phase):
        def stopping(self, state):
            save(self, state)
            saves.append(state.inside)
            if state.inside == (0, 2) and state.rows[-1]["phase"] == phase:
                raise KeyboardInterrupt

        return stopping

    for phase in ("coarse", "fine"):  # at the second outer iteration of each phase
        monkeypatch.setattr(Checkpoint, "save", save_then_stop_in(phase))
        with pytest.raises(KeyboardInterrupt):
            graphcal.calibrate(recording, quiet=True, checkpoint=path)
        assert path.is_file()
    stopped = len(saves)
    monkeypatch.setattr(Checkpoint, "save", save_then_stop_in("none"))
    with pytest.raises(ConfigError, match="checkpoint.npz: a checkpoint of another calibration: settings"):
        graphcal.calibrate(recording, CalibrationConfig(max_points=500_000), quiet=True, checkpoint=path)
    resumed = graphcal.calibrate(recording, quiet=True, checkpoint=path)
    assert saves[stopped] == (0, 3), saves  # went on with the next outer iteration
    assert not path.exists()
    assert [(row["phase"], row["stop"]) for row in resumed.history] == [(row["phase"], row["stop"])
                                                                        for row in whole.history]
    assert resumed.unobservable == whole.unobservable
    # 1e-7 m and rad: a ten-thousandth of the smallest sigmas (0.1 cm, 0.01 deg); measured 1e-11
    np.testing.assert_allclose(resumed.calibration.estimate.offsets, whole.calibration.estimate.offsets, atol=1e-7)
    assert resumed.calibration.estimate.extrinsic.equals(whole.calibration.estimate.extrinsic, 1e-7)


def test_a_checkpoint_that_is_not_one_is_refused_by_name(foreign_box_street, tmp_path):
    path = tmp_path / "checkpoint.npz"
    path.write_text("not a checkpoint")
    with pytest.raises(ConfigError, match="checkpoint.npz: not a graphcal checkpoint"):
        graphcal.calibrate(graphcal.Recording.load(foreign_box_street), quiet=True, checkpoint=path)
