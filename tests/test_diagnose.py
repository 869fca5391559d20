"""graphcal.diagnose end to end on concealed scenarios (scenarios/concealed.py): a clean recording
gets no finding, a recording with two left-out effects gets both, named and sized against the
simulator's truth; a recording against a simulation of the same drive names the effect between them.

Small sizes (about 110 k returns, 60 k used, 3 outer iterations, 2 per refit: about 45 s in all on
an idle machine): each effect here is several sigma at this size (at size 0.02 with 40 k returns the
azimuth eccentricity is no longer significant once the time offset is modelled). The per-effect figures at larger
sizes, for every candidate, are in benchmarks/bench_diagnose.py; the per-effect tests below use its
settings and run with GRAPHCAL_SLOW_TESTS=1 (1-2 min each).
"""

import json
from dataclasses import replace

import numpy as np
import pytest
import yaml
from rerun.chunk import RrdReader
from rrd_read import chunks, column
from scipy.spatial import cKDTree
from typer.testing import CliRunner

import graphcal
from factors.effects import candidate
from graphcal.calibration.config import CalibrationConfig
from graphcal.cli.main import app
from graphcal.cli.runs import DiagnoseOptions, diagnosis_run
from graphcal.simulation.script import load_scenario_builder

CONCEALED_SCENARIO = load_scenario_builder("concealed")
CONCEALED = CONCEALED_SCENARIO.__globals__["CONCEALED"]
SIZE = 0.03
# effects whose one-run spread at the per-effect tests' size is over 10 % of their size: their size is judged on
# the mean over seeds (incidence_range_bias, 160 k returns: sigma 13 %; seeds 1-4 gave -17, -6, -8, -9 %;
# azimuth_eccentricity: sigma 9 %, but seeds 1-3 gave -23.4, +5.3, +4.6 %, a spread of 16 %; heading_drift: sigma
# 11-13 %, seeds 1-2 gave +21.6, -6.7 %)
MANY_SEEDS = {"incidence_range_bias": (1, 2, 3, 4), "azimuth_eccentricity": (1, 2, 3), "heading_drift": (1, 2)}
# returns used per concealed effect (80 k unless here): on 80 k the incidence bias's subsample of seed 1 leaves its
# estimate at 1.45 +- 0.42 cm (seeds 2-4: 2.53-2.59), not significant after multiplicity; on 160 k every seed names
# it first (2.50, 2.81, 2.76, 2.73 cm for 3 cm)
MAX_POINTS = {"incidence_range_bias": 160_000}
VIEWER_POINTS = 5000


def config(mode: str = "joint", max_points: int = 60_000, iterations: int = 3) -> CalibrationConfig:
    return CalibrationConfig(mode=mode, max_points=max_points, stopping={
        "max_outer_iterations": iterations, "tolerance_m": 1e-3, "refuse_unconverged": False})


def recording(tmp_path_factory, name: str, **kwargs):
    rec = graphcal.simulate(CONCEALED_SCENARIO(size=SIZE, seed=0, **kwargs), quiet=True)
    return graphcal.Recording.load(rec.save(tmp_path_factory.mktemp("sim") / name))


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    return recording(tmp_path_factory, "clean", effect=None)


@pytest.fixture(scope="module")
def two_effects(tmp_path_factory):
    """The two-effect recording diagnosed as `graphcal diagnose --named-only` does, into a run folder (the
    generic discrepancies: the clean recording's test below and tests/test_open_world.py)."""
    rec = recording(tmp_path_factory, "two", effect="time_offset", effects=("azimuth_eccentricity",))
    run = diagnosis_run(rec.path, config(), DiagnoseOptions(max_effects=2, refit_iterations=2, open_world=False),
                        out=tmp_path_factory.mktemp("runs") / "run", viewer_points=VIEWER_POINTS, quiet=True)
    return rec, run


def test_clean_recording_gets_no_discovery_with_the_generic_models_on(clean):
    """open_world: a generic discrepancy of every channel against every regressor is tested too, and on a clean
    recording none is reported; every discrepancy was tested (a row each) and none is significant."""
    diagnosis = graphcal.diagnose(clean, config(), max_effects=1, quiet=True, open_world=True)
    assert diagnosis.findings == []
    tried = [c for c in diagnosis.candidates if "~" in c["effect"]]
    channels = {c["effect"].split("~")[0] for c in tried}
    regressors = {c["effect"].split("~")[1].split("/")[0] for c in tried}
    assert channels == {"range", "azimuth", "elevation", "time"}
    assert {"range", "intensity", "azimuth", "time", "incidence", "fibre"} <= regressors
    assert not any(c["significant"] for c in tried)
    assert f"{len(tried)} generic discrepancies" in diagnosis.summary() and "~" not in diagnosis.summary()
    # revolution stamps, applied at their known size and refitted, make the clean cloud worse
    (stamps,) = diagnosis.at_known_size
    assert stamps["effect"] == "intra_sweep_motion" and not stamps["accepted"]
    assert stamps["cost_cm2"][1] > stamps["cost_cm2"][0] and stamps["pairs"][1] < stamps["pairs"][0]


def test_streamed_linearisation_equals_the_whole_graphs_hessian(clean):
    """score.linearise makes the pairs' blocks one at a time and takes only the priors from gtsam: its information
    and vector equal gtsam's Hessian of the whole graph (every block factor, every candidate), in named coordinates."""
    import gtsam

    from graphcal.calibration.keys import E
    from graphcal.calibration.observability import tangent_to_axes
    from graphcal.diagnosis.diagnose import candidate_names, discrepancies
    from graphcal.diagnosis.fit import baseline
    from graphcal.diagnosis.score import linearise

    fit, _ = baseline(clean, config(max_points=20_000, iterations=2))
    names = candidate_names(fit, None, discrepancies(fit))
    problem = replace(fit.problem, effects=fit.with_candidates(names), lock=None)
    cluster, block = fit.clusters()
    lin = linearise(problem, fit.estimate, fit.pairs, cluster, block)
    graph, values = problem.graph(fit.estimate, fit.pairs, damped=False)
    keys = list(values.keys())
    information, vector = graph.linearize(values).hessian(gtsam.Ordering(keys))
    widths = [len(values.zeroVectors().at(k)) for k in keys]
    to_named = np.eye(sum(widths))
    s = int(np.sum(widths[:keys.index(E(0))]))
    to_named[s:s + 6, s:s + 6] = tangent_to_axes(fit.estimate.extrinsic.rotation().matrix())
    scale = np.abs(information).max()
    np.testing.assert_allclose(lin.information, to_named @ information @ to_named.T, atol=1e-9 * scale)
    np.testing.assert_allclose(lin.vector, to_named @ vector, atol=1e-9 * np.abs(vector).max())
    assert len(names) > 40 and len(lin.names) == len(lin.vector)


@pytest.mark.slow  # 20-30 s; the generic models' test above tests the named candidates too
def test_clean_recording_gets_no_false_alarm_from_the_named_candidates(clean):
    diagnosis = graphcal.diagnose(clean, config(), max_effects=1, quiet=True, open_world=False)
    assert diagnosis.findings == []
    assert len(diagnosis.candidates) >= 9  # every identifiable candidate was tested, with its MDB
    assert all(not c["significant"] for c in diagnosis.candidates)
    # revolution stamps, applied at their known size and refitted, make the clean cloud worse
    (stamps,) = diagnosis.at_known_size
    assert stamps["effect"] == "intra_sweep_motion" and not stamps["accepted"]
    assert stamps["cost_cm2"][1] > stamps["cost_cm2"][0] and stamps["pairs"][1] < stamps["pairs"][0]
    assert "no left-out effect is significant" in diagnosis.summary()


def test_two_concealed_effects_are_both_found_and_sized(two_effects):
    rec, run = two_effects
    diagnosis = run.diagnosis
    truth = rec.truth.effects
    found = {f["effect"]: f for f in diagnosis.findings}
    assert set(found) == {"time_offset", "azimuth_eccentricity"}, diagnosis.summary()
    # named first: the time offset, though the range offsets absorbed much of it (concealed)
    assert diagnosis.findings[0]["effect"] == "time_offset" and diagnosis.findings[0]["concealment_r2"] > 0.3
    assert found["time_offset"]["magnitude"] == pytest.approx(truth["time_offset"]["magnitude"], rel=0.2)
    assert found["azimuth_eccentricity"]["magnitude"] == pytest.approx(truth["azimuth_eccentricity"]["magnitude"],
                                                                       rel=0.2)
    for finding in diagnosis.findings:
        assert finding["energy_cm2"]["held_out_after"] < finding["energy_cm2"]["held_out_before"]
        assert finding["evidence"]["p_value"] < 1e-4 and np.isfinite(finding["sigma"]) and finding["sigma"] > 0
        # the size where both are re-solved together, not the first one's own step's
        value = diagnosis.fit.model.values[finding["effect"]]
        assert finding["magnitude"] == candidate(finding["effect"]).magnitude_of(value)
        assert finding["parameters"] == pytest.approx(np.atleast_1d(value).tolist())
        assert "re-solved with every effect found" in finding["statement"]
    assert diagnosis.energy_cm2["after"] < diagnosis.energy_cm2["before"]


def test_diagnosis_run_folder(two_effects):
    """diagnosis.json, the re-solved calibration with its effects, run.yaml's stages, and run.rrd read
    back with rerun's reader: the residual field of the final fit (at most VIEWER_POINTS pairs, local
    coordinates) and the binned effects."""
    rec, run = two_effects
    diagnosis, folder = run.diagnosis, run.folder
    saved = json.loads((folder / "diagnosis.json").read_text())
    assert saved["format"] == "graphcal-diagnosis/1"
    assert [f["effect"] for f in saved["findings"]] == [f["effect"] for f in diagnosis.findings]
    assert "ms" in saved["findings"][0]["statement"] or "deg" in saved["findings"][0]["statement"]
    calibration = (folder / "calibration" / "calibration.yaml").read_text()
    assert "time_offset" in calibration and "azimuth_eccentricity" in calibration
    manifest = yaml.safe_load((folder / "run.yaml").read_text())
    assert manifest["command"] == "diagnose" and manifest["recording"] == str(rec.path.resolve())
    page = (folder / "report.html").read_text()
    assert "Findings" in page and f"graphcal diagnosis report: {folder.name}" in page and ".partial" not in page
    for stage in ("load and validate the recording", "diagnose", "save results", "report", "viewer file"):
        assert manifest["timings_s"][stage] >= 0.0, stage
    assert len(RrdReader(folder / "run.rrd").blueprints()) == 1
    found = chunks(folder / "run.rrd")
    expected = {"/summary", "/world/residual/by_residual", "/world/residual/by_time_s", "/binned/fibre",
                "/binned/azimuth_deg"}
    assert expected <= set(found), expected - set(found)
    (positions,) = column(found["/world/residual/by_residual"], "Points3D:positions")
    fit = diagnosis.fit
    paired = fit.points_m[fit.pairs.index_p]
    assert len(positions) == min(len(paired), VIEWER_POINTS)
    distance, _ = cKDTree(paired).query(np.array(positions))
    assert distance.max() < 1e-3  # the final fit's points p, local coordinates (float32)
    ((summary,),) = column(found["/summary"], "TextDocument:text")
    assert diagnosis.findings[0]["statement"] in summary and "local origin" in summary


def test_recording_against_a_simulation_of_the_same_drive(clean, tmp_path_factory, tmp_path):
    rec = recording(tmp_path_factory, "offset", effect="time_offset")
    result = CliRunner().invoke(app, ["diagnose", str(rec.path), "--simulation", str(clean.path), "--out",
                                      str(tmp_path / "run"), "-q"])
    assert result.exit_code == 0, result.output
    manifest = yaml.safe_load((tmp_path / "run" / "run.yaml").read_text())
    assert manifest["simulation"] == str(clean.path.resolve()) and (tmp_path / "run" / "run.rrd").is_file()
    saved = json.loads((tmp_path / "run" / "diagnosis.json").read_text())
    assert saved["findings"][0]["effect"] == "time_offset"
    assert saved["findings"][0]["magnitude"] == pytest.approx(CONCEALED["time_offset"].magnitude, rel=0.2)


def test_a_large_effect_against_a_simulation_is_sized_by_re_pairing():
    """Revolution stamps move returns by up to a revolution of travel: at the nominal model many pair with
    the wrong simulated returns and the linear size fell 36 % short (bench_diagnose); refined with the
    recording re-paired at every step (compare._refined) it is within 20 %."""
    from graphcal.diagnosis.compare import compare

    scenario = dict(size=0.04, seed=1, effect=None)
    rec = graphcal.simulate(CONCEALED_SCENARIO(**scenario, effects=("intra_sweep_motion",)), quiet=True)
    diagnosis = compare(rec, graphcal.simulate(CONCEALED_SCENARIO(**scenario), quiet=True), max_points=80_000)
    assert diagnosis.findings[0]["effect"] == "intra_sweep_motion", diagnosis.summary()
    assert diagnosis.findings[0]["magnitude"] == pytest.approx(CONCEALED["intra_sweep_motion"].magnitude, rel=0.2)


@pytest.mark.slow  # 45-65 s; the stamps are refitted at their known size in the clean recording's test
def test_revolution_stamps_named_alone_once_a_linear_stand_in_is_re_solved(tmp_path_factory):
    """Returns stamped with their revolution's start (bench_diagnose's settings): intra_sweep_motion is
    named at its size; time_offset, significant by its linear step once it is modelled (chi2 21 for
    1.97 ms), is re-solved to a size within its sigma and withdrawn, not named. Named candidates only: with
    the generic discrepancies on it leaves the same finding (measured), at twice the cost."""
    rec = graphcal.simulate(CONCEALED_SCENARIO(size=0.04, seed=1, effect="intra_sweep_motion"), quiet=True)
    settings = CalibrationConfig(mode="joint", max_points=80_000, stopping={
        "max_outer_iterations": 6, "tolerance_m": 1e-4, "refuse_unconverged": False})
    diagnosis = graphcal.diagnose(rec, settings, max_effects=2, quiet=True, open_world=False)
    assert [f["effect"] for f in diagnosis.findings] == ["intra_sweep_motion"], diagnosis.summary()
    assert diagnosis.findings[0]["magnitude"] == pytest.approx(CONCEALED["intra_sweep_motion"].magnitude, rel=0.2)
    for row in diagnosis.withdrawn:
        assert row["refit_p_value"] > 1e-3 and abs(row["magnitude"]) < 3 * row["sigma"]


def test_bad_mode_is_a_clear_error(clean, tmp_path):
    result = CliRunner().invoke(app, ["diagnose", str(clean.path), "--mode", "sideways", "--out", str(tmp_path)])
    assert result.exit_code == 2 and "mode" in result.output


@pytest.mark.slow  # 2-5 min per effect
@pytest.mark.parametrize("effect", sorted(set(CONCEALED) - {"heading_bias"}))
def test_each_concealed_effect_is_named_first_and_sized(effect, tmp_path_factory):
    """Named first on every seed; the size within 20 % (on the mean over the seeds where one run's sigma
    is over 10 % of the size: MANY_SEEDS)."""
    magnitudes = []
    for seed in MANY_SEEDS.get(effect, (1,)):
        rec = graphcal.Recording.load(graphcal.simulate(CONCEALED_SCENARIO(size=0.04, seed=seed, effect=effect),
                                                        quiet=True).save(tmp_path_factory.mktemp("sim") / effect))
        settings = CalibrationConfig(mode=CONCEALED[effect].mode, max_points=MAX_POINTS.get(effect, 80_000), stopping={
            "max_outer_iterations": 6, "tolerance_m": 1e-4, "refuse_unconverged": False})
        diagnosis = graphcal.diagnose(rec, settings, max_effects=1, quiet=True)
        assert diagnosis.findings and diagnosis.findings[0]["effect"] == effect, diagnosis.summary()
        magnitudes.append(diagnosis.findings[0]["magnitude"])
    assert np.mean(magnitudes) == pytest.approx(CONCEALED[effect].magnitude, rel=0.2)


@pytest.mark.slow  # about 5 min
def test_heading_bias_is_reported_concealed_by_the_boresight_yaw(tmp_path_factory):
    rec = graphcal.simulate(CONCEALED_SCENARIO(size=0.04, seed=1, effect="heading_bias"), quiet=True)
    diagnosis = graphcal.diagnose(rec, config(max_points=80_000, iterations=3), max_effects=1, quiet=True)
    concealed = {c["effect"]: c for c in diagnosis.concealed}
    assert "heading_bias" in concealed and concealed["heading_bias"]["absorbed_by"][0] == "extrinsic.yaw_deg"
    assert "heading_bias" not in [f["effect"] for f in diagnosis.findings]
