"""Trajectory corrections estimated on a recording graphcal's simulator did not make (conftest.py's
foreign_box_street: a level head, 10 s, no second pass): the corrections take up what the drive shows of the lever
arm, and the calibration must say so, and hold an axis it sees only weakly, instead of reporting a lever arm it does
not know. The eight drives of bench_foreign.py --mode joint_trajectory: foreign_joint_trajectory.json."""

import numpy as np
import pytest

import graphcal
from graphcal.calibration.config import CalibrationConfig
from graphcal.calibration.evaluate import scorecard
from graphcal.calibration.observability import EXTRINSIC_NAMES


@pytest.mark.slow  # about 250 s: four calibrations, one interrupted
def test_with_trajectory_corrections_the_lever_arm_is_known_worse_named_and_held(foreign_box_street, tmp_path,
                                                                                 monkeypatch):
    from graphcal.calibration.checkpoint import Checkpoint

    recording = graphcal.Recording.load(foreign_box_street)
    joint = graphcal.calibrate(recording, CalibrationConfig(mode="joint"), quiet=True)
    with_trajectory = graphcal.calibrate(recording, CalibrationConfig(mode="joint_trajectory"), quiet=True)
    # adding nuisance parameters (the corrections) cannot sharpen the lever arm: measured 2.7, 2.2, 5.9 cm against
    # 0.28, 0.24, 1.4 cm (1-7 cm against under 1 cm on the 15 s drives of the benchmark)
    lever_joint, lever_trajectory = joint.sigmas.extrinsic[3:], with_trajectory.sigmas.extrinsic[3:]
    assert np.all(lever_trajectory > lever_joint), (lever_joint, lever_trajectory)
    # every lever-arm axis known more coarsely than accuracy's 1 cm is named, imprecise or unobservable, and the
    # verdict points to the survey that would decide it
    required = with_trajectory.config.accuracy.required(EXTRINSIC_NAMES)[3:]
    named = set(with_trajectory.calibration.imprecise) | set(with_trajectory.unobservable)
    coarse = {f"extrinsic.{axis}" for axis, sigma, need in zip(EXTRINSIC_NAMES[3:], lever_trajectory, required)
              if not sigma <= need}  # a held axis (NaN) is named unobservable
    assert coarse and coarse <= named, (coarse, named)
    assert "a surveyed lever arm as the nominal" in with_trajectory.verdict, with_trajectory.verdict
    # an axis whose sigma counting each return's noise once is above its prior's over sqrt(1 + 10) is seen weakly:
    # named unobservable and held at its nominal value (measured: the lever arm's z), the others fitted
    once = with_trajectory.shared_returns_uncertainty
    weak = [f"extrinsic.{axis}" for axis, sigma, p in zip(EXTRINSIC_NAMES[3:], once.extrinsic[3:],
                                                          once.extrinsic_prior[3:]) if sigma > p / np.sqrt(11.0)]
    assert weak, lever_trajectory
    for name in weak:
        assert name in with_trajectory.unobservable, name
        assert with_trajectory.calibration.reasons[name].startswith("seen weakly"), with_trajectory.calibration.reasons
    lever_arm_m = with_trajectory.calibration.estimate.extrinsic.translation()
    held = [EXTRINSIC_NAMES.index(name.removeprefix("extrinsic.")) - 3 for name in weak]
    np.testing.assert_allclose(lever_arm_m[held], np.asarray(recording.extrinsic.lever_arm_m)[held], atol=1e-4)
    # its value is the nominal's: its sigma is the nominal's error, its prior's (the data's is in the reason)
    np.testing.assert_allclose(with_trajectory.sigmas.extrinsic[3:][held], once.extrinsic_prior[3:][held])
    # interrupted right after the step that found them, and resumed: the uninterrupted calibration
    save = Checkpoint.save

    def stopped_once_found(self, state):
        save(self, state)
        if state.seen_weakly and state.inside is None:
            raise KeyboardInterrupt

    path = tmp_path / "checkpoint.npz"
    monkeypatch.setattr(Checkpoint, "save", stopped_once_found)
    with pytest.raises(KeyboardInterrupt):
        graphcal.calibrate(recording, CalibrationConfig(mode="joint_trajectory"), quiet=True, checkpoint=path)
    monkeypatch.setattr(Checkpoint, "save", save)
    resumed = graphcal.calibrate(recording, CalibrationConfig(mode="joint_trajectory"), quiet=True, checkpoint=path)
    # the same outer iterations, to the round-off of the extrinsic's rotation saved as a matrix and read back
    np.testing.assert_allclose([row["energy_cm2"] for row in resumed.history],
                               [row["energy_cm2"] for row in with_trajectory.history], rtol=1e-9)
    assert resumed.calibration.estimate.extrinsic.equals(with_trajectory.calibration.estimate.extrinsic, 1e-9)
    assert set(resumed.unobservable) == set(with_trajectory.unobservable)
    # the intrinsics still converge: over the determined parameters within the targets (cm, deg, deg, cm) on
    # this small recording (0.03 of the firings) but the elevation's, which the benchmark holds to 0.01 deg. Measured
    # 0.066 cm, 0.0029 deg, 0.0090 deg, 0.13 cm, 100 % within 3 sigmas, 31 % named (6 % unobservable)
    card = scorecard(with_trajectory, recording)
    assert card.within_3_sigma_determined >= 0.9, card
    assert np.all(np.asarray(card.rms_determined) <= [0.5, 0.01, 0.015, 0.5]), card
