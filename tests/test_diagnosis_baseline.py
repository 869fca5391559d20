"""graphcal.diagnose's baseline: a fit that leaves parameters far outside their priors, which calibrate would
refuse, is what a left-out effect often makes (a range scale pulls the upward fibres' heights): the diagnosis asks
for it unrefused and names what slid. The measured case: the level head's range scale in
benchmarks/results/diagnose_foreign_open_world_300k.json."""

import pytest

import graphcal
from graphcal.calibration.config import CalibrationConfig
from graphcal.diagnosis import diagnose as module
from graphcal.diagnosis.diagnose import Diagnosis


class Stop(Exception):
    pass


def test_the_baseline_is_asked_for_unrefused(monkeypatch):
    asked = []

    def baseline(recording, config, quiet=True):
        asked.append(config)
        raise Stop

    monkeypatch.setattr(module, "baseline", baseline)
    with pytest.raises(Stop):
        graphcal.diagnose(None, CalibrationConfig(mode="joint"), quiet=True)
    assert not asked[0].stopping.refuse_outside_priors
    assert CalibrationConfig().stopping.refuse_outside_priors  # calibrate's default refuses


def test_the_diagnosis_names_what_its_baseline_slid():
    slid = [{"parameter": "fibre_17.h_z_m", "prior_sigmas": 6.2}]
    diagnosis = Diagnosis([], [], [], [], [], [], {"before": 1.0}, 0.0, baseline_slid=slid)
    assert diagnosis.summary().startswith("without a left-out effect the calibration slid fibre_17.h_z_m (6 prior "
                                          "sigmas) far outside")
    assert diagnosis.to_json()["baseline_slid"] == slid
    assert Diagnosis([], [], [], [], [], [], {"before": 1.0}, 0.0).slid_statement is None
