"""Degenerate drives calibrated end to end with graphcal.calibrate's defaults: what each cannot observe follows from
its geometry (docs/reference/math.md "Weak directions"), and each result carries one plain line that says so and
names the manoeuvre or scene that would show it (graphcal.calibration.verdict).

Small noise-free recordings (a few seconds, about 1 % of an HDL-32E's firings) whose nominal model is the truth:
what is named comes from the drive and the scene, not from errors to find. The lever arm is (0.8, 0, 1.9) m."""

import html

import gtsam
import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

import graphcal
from graphcal.calibration.evaluate import scorecard
from graphcal.calibration.keys import X
from graphcal.calibration.problem import Problem
from graphcal.calibration.returns import initial_estimate
from graphcal.cli.main import app
from graphcal.recording.sensor import sensor_from_catalog
from graphcal.simulation.drive import Drive, spin, straight, turn
from graphcal.simulation.scenario import ExtrinsicSpec, Scenario
from graphcal.simulation.scene import Facade, Ground, Pole, street
from graphcal.simulation.starts import PITCHED_HEAD

COURTYARD = ((-20.0, -15.0), (25.0, -15.0), (25.0, 18.0), (-20.0, 18.0))


def courtyard() -> list:
    """Ground, four facades with pilasters and ledges around the origin (15 to 25 m away), three poles."""
    facades = [Facade(start_xy=COURTYARD[k], end_xy=COURTYARD[(k + 1) % 4], height_m=12.0, relief_spacing_m=5.0,
                      ledge_heights_m=(3.5, 7.0)) for k in range(4)]
    return [Ground(size_m=(80.0, 80.0))] + facades + [Pole(xy=xy) for xy in ((-8.0, 6.0), (10.0, -7.0), (5.0, 9.0))]


def scenario(name: str, scene: list, drive: Drive, duration_s: float, size: float = 0.01,
             extrinsic: ExtrinsicSpec = PITCHED_HEAD) -> Scenario:
    return Scenario(name=name, duration_s=duration_s, size=size, seed=1, extrinsic=extrinsic, scene=scene, drive=drive)


def calibrated(*args, **kwargs) -> graphcal.CalibrationResult:
    """calibrate, with its defaults, of the simulated scenario(*args, **kwargs)."""
    return graphcal.calibrate(graphcal.simulate(scenario(*args, **kwargs), quiet=True), quiet=True)


def extrinsic_named(result) -> set[str]:
    return {name.removeprefix("extrinsic.") for name in result.unobservable if name.startswith("extrinsic.")}


def test_a_straight_drive_names_the_lever_arm_and_the_roll_about_its_line():
    """The body never turns: a lever-arm error shifts every scan by the same world vector, and a roll about the
    driving line turns every scan about that same line, the cloud rigidly. A pitch or a yaw turns each scan about
    an axis across the line through its own place on it: the facades behind and ahead disagree, so they are seen."""
    scene = street(length_m=80.0, width_m=16.0, relief_spacing_m=5.0, start_x_m=-25.0, ledge_heights_m=(3.5, 7.0))
    result = calibrated("straight", scene, Drive(segments=straight(40.0), speed_knots=[(0.0, 6.0)]), 2.0, size=0.012)
    assert extrinsic_named(result) == {"roll_deg", "lever_arm_x_m", "lever_arm_y_m", "lever_arm_z_m"}
    assert result.verdict.startswith("this drive cannot observe the boresight roll, lever arm x and lever arm y (a drive "
                                     "with turns would show them); the lever arm z (a drive with slopes or banked turns")


def test_a_turn_on_the_spot_names_the_yaw_and_the_height_of_the_lever_arm():
    """The body only turns about its vertical axis. The sensor, 0.8 m off that axis, circles it: a moving sensor,
    not a static one, and a lever arm x error changes the circle's radius (seen), a boresight roll or pitch tilts
    each scan towards a direction that turns with the vehicle (seen). Turning the whole extrinsic about the body's
    vertical (the boresight yaw, the lever arm carried along in y) turns every scan about the turning axis: the
    cloud rigidly, unseen; so is a vertical shift (lever arm z) with no roll or pitch."""
    drive = Drive(segments=spin(370.0, 120.0), speed_knots=[(0.0, 0.0)])
    result = calibrated("spin", courtyard(), drive, 3.0, size=0.008)
    assert result.config.mode == "joint"  # calibrated as a moving sensor: intrinsics and extrinsic
    named = extrinsic_named(result)
    assert {"yaw_deg", "lever_arm_z_m"} <= named <= {"yaw_deg", "lever_arm_y_m", "lever_arm_z_m"}
    line = result.verdict
    assert line.startswith("this drive cannot observe the boresight yaw")
    assert "(a drive along a road would show" in line and "the lever arm z (a drive with slopes" in line
    assert "(a drive past facades, each surface seen from many places, would show them)" in line


def test_a_sensor_on_the_turning_axis_turning_on_the_spot_is_not_static():
    """The lever arm is zero: the sensor stays where it is (its positions span nothing) while the vehicle turns under
    it. No parallax, so its intrinsics are held as a static sensor's are; but its attitude turns, and the turn shows
    the boresight's roll and pitch (each scan tilted towards a direction that turns with the vehicle) and the lever
    arm across the axis (an error in x or y puts the modelled sensor on a circle the data do not make). Only the
    boresight yaw (turning the whole cloud about the axis) and the lever arm z stay unseen: the turn on the spot's
    verdict, not the static sensor's. The true boresight is 0.3 deg off in roll, -0.2 deg in pitch, the lever arm
    3 cm and -2 cm across."""
    extrinsic = PITCHED_HEAD.model_copy(update={"lever_arm_m": (0.0, 0.0, 1.9), "error_boresight_deg": (0.3, -0.2, 0.0),
                                                "error_lever_arm_m": (0.03, -0.02, 0.0)})
    drive = Drive(segments=spin(370.0, 120.0), speed_knots=[(0.0, 0.0)])
    recording = graphcal.simulate(scenario("spin on the axis", courtyard(), drive, 3.0, size=0.008,
                                           extrinsic=extrinsic), quiet=True)
    sensor_m = recording.truth.trajectory.position  # the body origin: the sensor is 1.9 m above it, on the axis
    assert np.ptp(sensor_m, axis=0).max() < 1e-6
    result = graphcal.calibrate(recording, quiet=True)
    assert result.config.mode == "joint"  # the extrinsic is estimated
    assert {name for name in result.unobservable if not name.startswith("fibre_")} == {"extrinsic.yaw_deg",
                                                                                     "extrinsic.lever_arm_z_m"}
    assert "static sensor" not in result.verdict and "a static sensor" not in result.calibration.reasons.values()
    assert result.verdict.startswith("this drive cannot observe the boresight yaw (a drive along a road would show it)"
                                     "; the lever arm z (a drive with slopes")
    assert "intrinsic parameters held" not in result.verdict and "31 fibre heights (a drive past facades" in result.verdict
    assert set(scorecard(result, recording).extrinsic_z) == {"roll_deg", "pitch_deg", "lever_arm_x_m", "lever_arm_y_m"}
    estimated, truth = result.calibration.extrinsic(), recording.truth.extrinsic
    np.testing.assert_allclose(estimated.boresight_deg[:2], truth.boresight_deg[:2], atol=0.05)  # 0.3 deg off at start
    np.testing.assert_allclose(estimated.lever_arm_m[:2], truth.lever_arm_m[:2], atol=0.005)  # 3 cm off at start


def test_a_drive_with_turns_on_a_flat_plain_names_what_the_ground_cannot_show():
    """A level head over a plain with nothing on it. The ground's normal is vertical everywhere: a horizontal shift
    (lever arm x, y) or a turn about the vertical (boresight yaw, every fibre's azimuth offset) leaves it on itself,
    and so does a vertical shift of every scan (lever arm z) while the vehicle neither rolls nor pitches; a tilt of
    the head shows, towards a direction that turns with the vehicle. A fibre aimed level or up sees nothing; one
    aimed down sees the ground at one range, the ring's height: one number for its range offset, elevation and
    height, so two of the three at least are named."""
    drive = Drive(segments=straight(8.0) + turn(10.0, 90.0) + straight(20.0), speed_knots=[(0.0, 6.0)])
    result = calibrated("plain", [Ground(size_m=(300.0, 300.0))], drive, 5.0, extrinsic=ExtrinsicSpec())
    assert extrinsic_named(result) == {"yaw_deg", "lever_arm_x_m", "lever_arm_y_m", "lever_arm_z_m"}
    named = set(result.unobservable)
    sensor = sensor_from_catalog("HDL-32E")
    for fibre in np.flatnonzero(np.arange(sensor.n_fibres) != sensor.reference_fibre):
        assert f"fibre_{fibre}.d_azimuth_deg" in named, fibre
        ring = {kind for kind in ("d_range_m", "d_elevation_deg", "h_z_m") if f"fibre_{fibre}.{kind}" in named}
        assert len(ring) == 3 if sensor.elevation_deg[fibre] >= 0 else len(ring) >= 2, (fibre, ring)
    line = result.verdict
    assert line.startswith("this drive cannot observe the boresight yaw, lever arm x and lever arm y (facades or poles "
                           "beside the road, not only flat ground, would show them); the lever arm z (a drive with "
                           "slopes")
    assert "fibre heights (fibres that see surfaces at several ranges and orientations" in line


def test_a_standstill_prints_one_plain_line_through_the_command_line(tmp_path):
    """A vehicle that does not move: every scan is one viewpoint, and the extrinsic and a common motion of the
    trajectory move the whole cloud rigidly. The command line prints the static sensor's line, not the 130 names."""
    recording = graphcal.simulate(scenario("standstill", courtyard(), Drive(segments=straight(1.0),
                                                                             speed_knots=[(0.0, 0.0)]), 2.0),
                                  quiet=True).save(tmp_path / "rec")
    run = CliRunner().invoke(app, ["calibrate", str(recording), "--out", str(tmp_path / "run"), "--no-evaluate",
                                   "--viewer-points", "1000"])
    assert run.exit_code == 0, run.output
    lines = run.output.strip().splitlines()
    verdicts = [line for line in lines if "unobservable" in line]
    assert len(verdicts) == 1 and verdicts[0].startswith(
        "static sensor: the extrinsic and the trajectory are unobservable; 126 intrinsic parameters held")  # 4 x 31 + 2
    assert len(lines) <= 6 and "fibre_" not in run.output
    calibration = yaml.safe_load((tmp_path / "run" / "calibration.yaml").read_text())
    assert verdicts[0].startswith(calibration["verdict"])
    assert html.escape(calibration["verdict"]) in (tmp_path / "run" / "report.html").read_text()


@pytest.fixture(scope="module")
def street_then_field():
    """A straight street of facades 40 m long, then 60 m of open ground beyond the head's 40 m range (max_range_m),
    driven at 10 m/s from x = -5 m."""
    scene = [Ground(center_xy=(50.0, 0.0), size_m=(200.0, 60.0)),
             Facade(start_xy=(30.0, 8.0), end_xy=(-10.0, 8.0), relief_spacing_m=5.0, ledge_heights_m=(3.5,)),
             Facade(start_xy=(-10.0, -8.0), end_xy=(30.0, -8.0), relief_spacing_m=5.0, ledge_heights_m=(3.5,)),
             Pole(xy=(5.0, 5.0)), Pole(xy=(15.0, -5.0))]
    drive = Drive(segments=straight(120.0), speed_knots=[(0.0, 10.0), (10.0, 10.0)], start_xy=(-5.0, 0.0))
    return graphcal.simulate(Scenario(name="street_then_field", duration_s=9.5, size=0.02, seed=1, scene=scene,
                                      drive=drive, extrinsic=PITCHED_HEAD, max_range_m=40.0), quiet=True)


@pytest.mark.parametrize("deformation", ["monnier", "prior"])
def test_the_control_sigmas_are_about_the_drives_mean(street_then_field, deformation):
    """No pair sees the drive's common translation (it is named; E_def's anchors hold it), so every control's
    marginal carries its variance: the reported sigmas leave it out. Against the covariance of x_c - mean(x) from
    GTSAM's joint marginals of every control, under both forms of E_def, at the nominal (here the true) model."""
    config = graphcal.CalibrationConfig(mode="trajectory", trajectory={"deformation": deformation})
    problem = Problem.of(street_then_field, config).in_phase("fine")
    estimate = initial_estimate(street_then_field, problem.full)
    final = problem.final(estimate)
    graph, values = problem.graph(estimate, final.pairs, damped=False)
    controls = len(estimate.corrections)
    joint = gtsam.Marginals(graph, values).jointMarginalCovariance([X(c) for c in range(controls)]).fullMatrix()
    about_mean = np.kron(np.eye(controls) - 1.0 / controls, np.eye(3))
    expected_m = np.sqrt(np.diag(about_mean @ joint @ about_mean)).reshape(controls, 3)
    np.testing.assert_allclose(final.uncertainty.controls[:, 3:], expected_m, rtol=1e-3)
    # with the common translation's variance left in, every control would be known no better than E_def's term
    assert np.sqrt(np.diag(joint)).reshape(controls, 3).min() > 1.2 * expected_m.min()


def test_a_street_that_ends_in_an_open_field_names_the_corrections_the_field_cannot_show(street_then_field):
    """Once the facades are out of reach only the ground's normal is seen, so the trajectory corrections there
    are named along the ground (x, y), never in height; in the street the facades show the across-track (y)."""
    recording = street_then_field
    result = graphcal.calibrate(recording, graphcal.CalibrationConfig(mode="trajectory"), quiet=True)
    named = set(result.unobservable)
    x_m = -5.0 + 10.0 * (result.calibration.control_times_s - result.calibration.control_times_s[0])
    interval_m = 10.0  # a control's interval on each side: 1 s at 10 m/s
    field = np.flatnonzero(x_m - interval_m > 30.0 + 40.0)  # every return of the controls' intervals beyond the range
    street_ = np.flatnonzero(x_m + interval_m < 30.0)  # ... and between the facades
    assert len(field) >= 2 and len(street_) >= 3
    assert all({f"control_{c}.x_m", f"control_{c}.y_m"} <= named for c in field), sorted(named)
    assert not any(f"control_{c}.y_m" in named for c in street_), sorted(named)
    assert not any(name.endswith(".z_m") for name in named)
    assert "too little structure near t = " in result.calibration.reasons[f"control_{field[0]}.y_m"]
    sigma_m = result.sigmas.controls[:, 3:]  # the names are the reported sigmas above the 1 cm noise
    assert {f"control_{c}.{axis}" for c, k in zip(*np.nonzero(sigma_m > 0.01)) for axis in [("x_m", "y_m", "z_m")[k]]} \
        == {name for name in named if name.startswith("control_")}
    assert "the trajectory corrections at" in result.verdict
