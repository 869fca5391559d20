"""End-to-end calibration on reduced-size simulations, checked against the simulator's truth/.

Full-size acceptance figures (seed Table 4.1 thresholds) are in benchmarks/bench_calibrate.py;
these tests use ~100 k returns and a bounded number of outer iterations, so their thresholds
are looser and say what this size reaches.
"""

import re

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

import graphcal
from graphcal.calibration.calibrate import calibrate
from graphcal.calibration.config import CalibrationConfig
from graphcal.calibration.evaluate import (
    apply_calibration,
    evaluate,
    intrinsic_rms,
    nominal_calibration,
)
from graphcal.calibration.result import Calibration
from graphcal.simulation.scenario import ExtrinsicSpec, IntrinsicErrors
from graphcal.simulation.scene import ParkedCar
from graphcal.simulation.script import load_scenario_builder
from graphcal.simulation.starts import FAR_START_PRIORS

SIM2 = load_scenario_builder("sim2_street")


@pytest.fixture(scope="module")
def street_with_traffic(tmp_path_factory):
    """sim2_street (Table 4.1 start) with two cars driving past: moving clutter."""
    scenario = SIM2(size=0.03, seed=1)
    traffic = [ParkedCar(xy=(-5.0, 2.0), velocity_m_s=(8.0, 0.0, 0.0)),
               ParkedCar(xy=(40.0, -2.5), yaw_deg=180.0, velocity_m_s=(-7.0, 0.0, 0.0))]
    scenario = scenario.model_copy(update={"scene": scenario.scene + traffic})
    return graphcal.Recording.load(graphcal.simulate(scenario, quiet=True).save(tmp_path_factory.mktemp("sim") / "rec"))


@pytest.fixture(scope="module")
def street_result(street_with_traffic):
    return calibrate(street_with_traffic, CalibrationConfig(mode="intrinsic", priors=FAR_START_PRIORS, stopping={
        "max_outer_iterations": 40, "tolerance_m": 1e-4}), quiet=True)


def test_intrinsics_from_table_4_1_start_despite_moving_clutter(street_with_traffic, street_result):
    truth = street_with_traffic.truth.intrinsics
    before = intrinsic_rms(np.zeros_like(truth), truth, 15)
    after = intrinsic_rms(street_result.calibration.estimate.offsets, truth, 15)
    np.testing.assert_allclose(before, [10.0, 2.5, 3.0, 10.0], rtol=1e-6)  # the seed's start
    assert after[0] < 0.2 and after[1] < 0.01 and after[2] < 0.02 and after[3] < 0.5, after  # cm, deg, deg, cm
    j_before, j_after = street_result.energy_cm2
    assert j_before > 20 and j_after < 0.05
    assert street_result.unobservable == ()
    sigma = np.delete(street_result.uncertainty.intrinsics, 15, axis=0)
    assert np.all(np.isfinite(sigma)) and np.all(sigma > 0)
    reported = street_result.sigmas.intrinsics[15]  # its range and elevation estimated, the gauges held (null)
    assert np.all(np.isfinite(reported[[0, 2]])) and np.isnan(reported[[1, 3]]).all()
    reference = street_result.uncertainty.intrinsics[15]  # SI
    error = street_result.calibration.estimate.offsets[15] - truth[15]
    assert np.all(np.abs(error[[0, 2]]) < 3 * reference[[0, 2]]), (error, reference)


def test_result_saved_loaded_and_applied(street_with_traffic, street_result, tmp_path):
    path = street_result.save(tmp_path / "run")
    assert {p.name for p in (tmp_path / "run").iterdir()} >= {"calibration.yaml", "config.yaml", "history.csv",
                                                              "residuals.parquet"}
    loaded = Calibration.load(path, street_with_traffic.sensor)
    np.testing.assert_allclose(loaded.estimate.offsets, street_result.calibration.estimate.offsets, atol=1e-9)
    evaluation = evaluate(street_result, street_with_traffic)
    assert evaluation.cloud_after.median < 0.2 * evaluation.cloud_before.median
    applied = apply_calibration(loaded, street_with_traffic)
    assert applied.shape == (len(street_with_traffic.points), 3)


def test_a_calibration_with_the_effects_a_diagnosis_writes_loads(street_with_traffic, street_result, tmp_path):
    """diagnose's calibration.yaml lists its findings and the constants solved beside them (a range curve's
    range_offset): each is a name the file may hold."""
    path = street_result.save(tmp_path / "run")
    content = yaml.safe_load(path.read_text())
    content["effects"] = [{"effect": "discovered", "magnitude": 0.02, "sigma": 0.001, "unit": "m",
                           "parameters": [0.01, 0.02], "statement": "a range curve"},
                          {"effect": "range_offset", "magnitude": 0.013, "sigma": 0.002, "unit": "m",
                           "parameters": [0.013], "statement": "solved beside it"}]
    path.write_text(yaml.safe_dump(content))
    loaded = Calibration.load(path, street_with_traffic.sensor)
    np.testing.assert_allclose(loaded.estimate.offsets, street_result.calibration.estimate.offsets, atol=1e-9)


@pytest.mark.parametrize("edit, field", [
    (lambda d: d.update(extrinsic=[0.8, 0.0, 1.9]), "extrinsic"),
    (lambda d: d["sensor"].update(reference_fibre=3), "sensor.reference_fibre"),
    (lambda d: d["intrinsics"][4].update(d_range_m="1 cm"), "intrinsics[4].d_range_m"),
    (lambda d: d["intrinsics"].pop(), "intrinsics"),
    (lambda d: d.update(trajectory_corrections=[{"time": 1.0, "d_position_m": [0.0, 0.1]},
                                                {"time": 2.0}]), "trajectory_corrections[0].d_position_m"),
    (lambda d: d.update(trajectory_corrections=[{"time": 2.0}, {"time": 1.0}]), "trajectory_corrections.time"),
])
def test_bad_calibration_yaml_names_the_field(street_with_traffic, street_result, tmp_path, edit, field):
    path = street_result.save(tmp_path / "run")
    content = yaml.safe_load(path.read_text())
    edit(content)
    path.write_text(yaml.safe_dump(content))
    with pytest.raises(graphcal.RecordingError, match=re.escape(f"field '{field}'")) as error:
        Calibration.load(path, street_with_traffic.sensor)
    assert "calibration.yaml" in str(error.value)


def test_true_calibration_applied_gives_the_true_cloud(street_with_traffic):
    """apply_calibration against the simulator's per-return true positions (independent path)."""
    truth = street_with_traffic.truth
    nominal = nominal_calibration(street_with_traffic)
    true = Calibration(nominal.sensor_model, nominal.reference_fibre,
                       type(nominal.estimate)(truth.intrinsics, nominal.estimate.extrinsic, ()), np.zeros(0))
    np.testing.assert_allclose(apply_calibration(true, street_with_traffic), truth.world_points(), atol=1e-4)


def test_level_head_leaves_what_the_road_cannot_tell_apart_unobservable():
    """Level, each of the lowest fibres sees mostly the flat road, at one range: d_range sin(phi) +
    r cos(phi) d_elevation + Hz is all the road measures of it, and a ring turned about the vertical stays
    on the road. At the true calibration the weak directions must name parameters of those fibres, and
    not the range, azimuth or elevation of the top fibre, which sees the facades."""
    from graphcal.calibration.config import ESTIMATES
    from graphcal.calibration.priors import Priors
    from graphcal.calibration.problem import Problem
    from graphcal.calibration.returns import initial_estimate, prepare

    scenario = SIM2(size=0.1, seed=2).model_copy(update={
        "extrinsic": ExtrinsicSpec(boresight_deg=(0.0, 0.0, 90.0)), "intrinsic_errors": IntrinsicErrors()})
    recording = graphcal.simulate(scenario, quiet=True)
    data = prepare(recording, 1.0)
    config = CalibrationConfig().for_sensor(data.static, data.range_noise_m)
    truth = initial_estimate(recording, data)  # no intrinsic error was drawn: the nominal model is the truth
    problem = Problem(data, config, ESTIMATES["intrinsic"], truth.extrinsic,
                      Priors.of(config, data.sensor.n_fibres, len(data.control_times_s)))
    named = problem.weak_directions(truth).named()
    by_elevation = recording.sensor.fibres_by_elevation()
    for fibre in by_elevation[:2]:
        assert any(name.startswith(f"fibre_{fibre}.") for name in named), named
    top = by_elevation[-1]  # the facades show its range, azimuth and elevation (its height only the ledges' faces)
    assert not {f"fibre_{top}.{name}" for name in ("d_range_m", "d_azimuth_deg", "d_elevation_deg")} & set(named)


def test_straight_drive_leaves_the_lever_arm_and_roll_unobservable(tmp_path):
    """On a straight drive the body never turns: a lever-arm error shifts every scan by the same
    world vector, and a roll about the driving direction turns the whole cloud rigidly about the
    driving line; no self-consistency energy sees either. Those four must be named unobservable,
    held at nominal (their sigma the prior's in the yaml); pitch and yaw (which move a surface differently
    when seen ahead and behind) stay estimated and come back to the truth."""
    scenario = SIM2(size=0.02, seed=3)
    scenario = scenario.model_copy(update={
        "intrinsic_errors": IntrinsicErrors(),
        "extrinsic": scenario.extrinsic.model_copy(update={"error_lever_arm_m": (0.1, -0.1, 0.2),
                                                          "error_boresight_deg": (0.5, -0.4, 0.6)})})
    recording = graphcal.Recording.load(graphcal.simulate(scenario, quiet=True).save(tmp_path / "rec"))
    result = calibrate(recording, CalibrationConfig(mode="extrinsic", stopping={"max_outer_iterations": 15}), quiet=True)
    unseen = {"extrinsic.roll_deg", "extrinsic.lever_arm_x_m", "extrinsic.lever_arm_y_m", "extrinsic.lever_arm_z_m"}
    assert set(result.unobservable) == unseen
    line = result.verdict
    assert "boresight roll, lever arm x and lever arm y (a drive with turns would show them)" in line
    assert "lever arm z (a drive with slopes or banked turns" in line
    estimate = result.calibration.estimate.extrinsic
    np.testing.assert_allclose(estimate.translation(), recording.extrinsic.lever_arm_m, atol=1e-6)  # held at nominal
    error_deg = Rotation.from_matrix(recording.truth.extrinsic.R_body_lidar @ estimate.rotation().matrix().T
                                     ).as_rotvec(degrees=True)  # body axes: roll, pitch, yaw
    nominal_error_deg = Rotation.from_matrix(recording.truth.extrinsic.R_body_lidar @ recording.extrinsic.R_body_lidar.T
                                             ).as_rotvec(degrees=True)
    assert np.all(np.abs(nominal_error_deg[1:]) > 0.3) and np.all(np.abs(error_deg[1:]) < 0.005), error_deg
    saved = yaml.safe_load(result.save(tmp_path / "run").read_text())
    # held at the nominal value: its sigma is the nominal's stated uncertainty (the prior's), not the data's
    sigma = saved["extrinsic"]["sigma"]
    np.testing.assert_allclose(sigma["lever_arm_m"], [0.1, 0.1, 0.1], rtol=0.01)
    assert sigma["boresight_deg"][0] == pytest.approx(1.0, rel=0.01) and max(sigma["boresight_deg"][1:]) < 0.01
    assert unseen <= set(saved["unobservable"]) and set(saved["unobservable_reasons"]) == unseen
