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

    def baseline(recording, config, quiet=True, checkpoint=None):
        asked.append((config, checkpoint))
        raise Stop

    monkeypatch.setattr(module, "baseline", baseline)
    with pytest.raises(Stop):
        graphcal.diagnose(None, CalibrationConfig(mode="joint"), quiet=True, checkpoint="here.npz")
    assert not asked[0][0].stopping.refuse_outside_priors
    assert asked[0][1] == "here.npz"  # an interrupted diagnosis resumes its baseline calibration
    assert CalibrationConfig().stopping.refuse_outside_priors  # calibrate's default refuses


def test_the_diagnosis_names_what_its_baseline_slid():
    slid = [{"parameter": "fibre_17.h_z_m", "prior_sigmas": 6.2}]
    diagnosis = Diagnosis([], [], [], [], [], [], {"before": 1.0}, 0.0, baseline_slid=slid)
    assert diagnosis.summary().startswith("without a left-out effect the calibration slid fibre_17.h_z_m (6 prior "
                                          "sigmas) far outside")
    assert diagnosis.to_json()["baseline_slid"] == slid
    assert Diagnosis([], [], [], [], [], [], {"before": 1.0}, 0.0).slid_statement is None


def test_diagnose_keeps_its_baselines_checkpoint_beside_the_run_and_resume_uses_it(monkeypatch, tmp_path):
    """Ctrl-C during the baseline: exit 130, the checkpoint beside --out named; --resume hands it to the baseline,
    a run without --resume starts afresh (the checkpoint removed first)."""
    from typer.testing import CliRunner

    from graphcal.cli.main import app
    from graphcal.simulation.script import load_scenario_builder

    recording = graphcal.simulate(load_scenario_builder("sim2_street")(size=0.01, seed=0), quiet=True)
    recording.save(tmp_path / "rec")
    checkpoint, there = tmp_path / ".run.checkpoint.npz", []

    def interrupted(recording, config, quiet=True, checkpoint=None):
        there.append(checkpoint.is_file())
        checkpoint.write_bytes(b"state")  # as calibrate saves it
        raise KeyboardInterrupt

    monkeypatch.setattr(module, "baseline", interrupted)
    command = ["diagnose", str(tmp_path / "rec"), "--out", str(tmp_path / "run")]
    for extra, existed in (([], False), (["--resume"], True), ([], False)):
        result = CliRunner().invoke(app, command + extra)
        assert result.exit_code == 130 and f"kept in {checkpoint}: the same command with --resume" in result.output
        assert there[-1] == existed and not (tmp_path / "run").exists()
