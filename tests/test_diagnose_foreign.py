"""graphcal.diagnose on a recording it was not fitted to: the independent simulator (tools/foreign_sim, its own
firing order, encoder jitter, intensity, INS noise and true intrinsic and extrinsic errors) with a range scale
written from its physics there. The finder names it first, within 20 % of truth/effects.yaml's magnitude.

Small: a 15 s level box street at size 0.03 (about 300 k returns, 40 k used), 3 outer iterations, the named
candidates only. The figures for every departure at size 0.1: benchmarks/bench_diagnose_foreign.py.
"""

import pytest

import graphcal
from graphcal.calibration.config import CalibrationConfig
from tools.foreign_sim import Departures, simulate


def test_a_range_scale_of_the_independent_simulator_is_named_first_and_sized(tmp_path):
    directory = simulate("box_street", tmp_path / "range_scale", duration_s=15.0, size=0.03, seed=2, mount="level",
                         departures=Departures(range_scale=0.0015))
    recording = graphcal.Recording.load(directory)
    settings = CalibrationConfig(mode="joint", max_points=40_000, stopping={
        "max_outer_iterations": 3, "tolerance_m": 1e-3, "refuse_unconverged": False})
    diagnosis = graphcal.diagnose(recording, settings, max_effects=1, quiet=True, open_world=False)
    assert diagnosis.findings and diagnosis.findings[0]["effect"] == "range_scale", diagnosis.summary()
    true = recording.truth.effects["range_scale"]["magnitude"]
    assert diagnosis.findings[0]["magnitude"] == pytest.approx(true, rel=0.2)


def test_clean_recordings_of_the_independent_simulator_get_at_most_one_discovery_in_four(tmp_path):
    """With the generic discrepancies on, curves that fit the pipeline's own misfit of this street (the elevation
    against the incidence, the azimuth or the intensity, the range against the range) pass the linear tests; once
    re-solved with them J, the mean over their pairs and the control's, mostly does not fall by its floor below the
    fit without them re-solved as long, and they are withdrawn. At this size (40 k returns, 6 outer iterations) one
    seed in four gets a false discovery, and which one depends on the machine's rounding: seed 0 here (the elevation
    against the intensity, J 1.13 -> 1.11 cm2), seed 1 on an earlier machine (docs/dev/open-questions.md). With 3
    outer iterations the baseline is further from converged and seed 3 discovers the elevation against the incidence
    too (J 0.872 -> 0.855 cm2), a curve that fits the unfinished fit's misfit. Four seeds, at most one discovery, and
    every withdrawal for the stated reason."""
    discoveries, withdrawn = 0, []
    for seed in range(4):
        directory = simulate("box_street", tmp_path / f"clean{seed}", duration_s=15.0, size=0.03, seed=seed,
                             mount="level")
        recording = graphcal.Recording.load(directory)
        settings = CalibrationConfig(mode="joint", max_points=40_000, stopping={
            "max_outer_iterations": 6, "tolerance_m": 1e-3, "refuse_unconverged": False})
        diagnosis = graphcal.diagnose(recording, settings, max_effects=1, quiet=True, open_world=True)
        discoveries += bool(diagnosis.findings)
        withdrawn += [w for w in diagnosis.withdrawn if w["energy_cm2"]["before"] is not None]
    assert discoveries <= 1
    assert withdrawn and all(w["energy_cm2"]["after"] > w["energy_cm2"]["before"] - w["energy_cm2"]["floor"]
                             for w in withdrawn)
    assert all("does not lower J by its floor" in w["statement"] for w in withdrawn)
