"""graphcal.diagnose's baseline (diagnose._baseline): a calibration that slid parameters far outside their priors
(a left-out effect is often what such a slide absorbs) is made again with them held at nominal, and the diagnosis
says so; a second slide is refused. The measured case: benchmarks/results/diagnose_foreign_open_world_300k.json
(range scale, level head)."""

import pytest

from graphcal.calibration.config import CalibrationConfig
from graphcal.common.errors import PriorsExceeded
from graphcal.diagnosis import diagnose as module
from graphcal.diagnosis.diagnose import Diagnosis

SLID = PriorsExceeded("rec: 1 parameter(s) slid far outside", ("fibre_17.h_z_m",), ("fibre_*.d_azimuth_deg",
                                                                                    "fibre_17.h_z_m"))


def test_a_slid_baseline_is_made_again_holding_what_slid(monkeypatch):
    holds = []

    def baseline(recording, config, quiet=True):
        holds.append(config.static.hold)
        if len(holds) == 1:
            raise SLID
        return "fit", "result"

    monkeypatch.setattr(module, "baseline", baseline)
    assert module._baseline(None, CalibrationConfig(), True) == ("fit", "result", ("fibre_17.h_z_m",))
    assert holds == [None, ("fibre_*.d_azimuth_deg", "fibre_17.h_z_m")]


def test_a_second_slide_is_refused(monkeypatch):
    def baseline(recording, config, quiet=True):
        raise SLID

    monkeypatch.setattr(module, "baseline", baseline)
    with pytest.raises(PriorsExceeded, match="slid far outside"):
        module._baseline(None, CalibrationConfig(), True)


def test_the_diagnosis_says_what_its_baseline_held():
    diagnosis = Diagnosis([], [], [], [], [], [], {"before": 1.0}, 0.0, baseline_held=("fibre_17.h_z_m",))
    assert diagnosis.summary().startswith("the calibration without a left-out effect slid fibre_17.h_z_m far outside")
    assert diagnosis.to_json()["baseline_held"] == ["fibre_17.h_z_m"]
    assert Diagnosis([], [], [], [], [], [], {"before": 1.0}, 0.0).held_statement is None
