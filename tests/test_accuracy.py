"""Parameters determined more coarsely than required (graphcal.calibration.accuracy): named with their sigma,
fitted values kept; against sigmas written by hand. The foreign benchmarks measure the rule on drives
(benchmarks/results/foreign*.json: what it names and the error of what it does not)."""

import numpy as np
import pytest

from graphcal.calibration.accuracy import imprecise
from graphcal.calibration.config import AccuracySettings, CalibrationConfig
from graphcal.calibration.observability import Uncertainty
from graphcal.calibration.verdict import Motion, verdict

TURNING = Motion(travelled=True, turned=True, tilted=False)


def _sigmas(extrinsic: np.ndarray | None = None) -> Uncertainty:
    """1-sigmas in file units (m, deg) for 4 fibres: fibre 0 within every default, fibre 1's elevation 0.03 deg,
    fibre 2's height 1 cm and range 0.4 cm, fibre 3 held (NaN); the extrinsic's as given (None: not estimated)."""
    intrinsics = np.array([[0.001, 0.002, 0.004, 0.002],
                           [0.001, 0.002, 0.03, 0.002],
                           [0.004, 0.002, 0.004, 0.01],
                           [np.nan] * 4])
    return Uncertainty(intrinsics, np.full((4, 4), 0.02), extrinsic, None, None, None)


def test_each_parameter_coarser_than_its_kind_is_named_with_its_sigma():
    reasons = imprecise(_sigmas(), AccuracySettings(), named=set())
    assert set(reasons) == {"fibre_1.d_elevation_deg", "fibre_2.h_z_m"}
    assert reasons["fibre_1.d_elevation_deg"].startswith("imprecise: determined to 0.03 deg (1 sigma), coarser than "
                                                         "the 0.01 deg required (accuracy.intrinsic_angle_deg)")
    assert "determined to 1 cm (1 sigma), coarser than the 0.5 cm required (accuracy.intrinsic_range_m)" \
        in reasons["fibre_2.h_z_m"]


def test_an_extrinsic_axis_coarser_than_required_is_named_and_a_held_one_is_not():
    # roll, pitch, yaw [deg], lever arm x, y, z [m]: the pitch 0.03 deg, the lever arm's z 2 cm, its y held
    sigma = np.array([0.002, 0.03, 0.004, 0.003, np.nan, 0.02])
    reasons = imprecise(_sigmas(sigma), AccuracySettings(), named=set())
    assert {"extrinsic.pitch_deg", "extrinsic.lever_arm_z_m"} <= set(reasons)
    assert not {"extrinsic.roll_deg", "extrinsic.yaw_deg", "extrinsic.lever_arm_x_m", "extrinsic.lever_arm_y_m"} \
        & set(reasons)
    assert "determined to 2 cm (1 sigma), coarser than the 1 cm required (accuracy.extrinsic_lever_arm_m)" \
        in reasons["extrinsic.lever_arm_z_m"]
    assert "(accuracy.extrinsic_boresight_deg)" in reasons["extrinsic.pitch_deg"]
    off = AccuracySettings(extrinsic_boresight_deg=None, extrinsic_lever_arm_m=0.05)
    assert not {name for name in imprecise(_sigmas(sigma), off, named=set()) if name.startswith("extrinsic.")}


def test_a_name_already_given_or_a_kind_not_required_is_not_named_again():
    assert set(imprecise(_sigmas(), AccuracySettings(), named={"fibre_2.h_z_m"})) == {"fibre_1.d_elevation_deg"}
    loose = AccuracySettings(intrinsic_angle_deg=None, intrinsic_range_m=0.003)
    assert set(imprecise(_sigmas(), loose, named=set())) == {"fibre_2.h_z_m", "fibre_2.d_range_m"}


def test_the_accuracy_section_reads_from_settings_and_refuses_a_non_positive_one():
    config = CalibrationConfig.model_validate({"accuracy": {"intrinsic_angle_deg": 0.05}})
    assert config.accuracy.required().tolist() == [0.005, 0.05, 0.05, 0.005]
    assert config.accuracy.required(("pitch_deg", "lever_arm_z_m")).tolist() == [0.01, 0.01]
    with pytest.raises(ValueError, match="intrinsic_range_m"):
        CalibrationConfig.model_validate({"accuracy": {"intrinsic_range_m": 0}})


def test_the_verdict_tells_imprecise_parameters_from_those_it_cannot_observe():
    weak = ["fibre_3.h_z_m"]
    coarse = ["fibre_1.d_elevation_deg", "fibre_2.d_elevation_deg", "fibre_2.h_z_m"]
    line = verdict(weak, {name: "..." for name in weak + coarse}, TURNING, coarse)
    assert line.startswith("this drive cannot observe 1 fibre height (fibres that see surfaces at several ranges")
    assert line.endswith("held at nominal or bound by the prior; it determines 2 fibre elevations and 1 fibre height "
                         "(fibres that see surfaces at several ranges and orientations (facades beside the road, not "
                         "only flat ground) would sharpen them) more coarsely than required: their fitted values "
                         "kept")
    assert verdict([], {}, TURNING, coarse).startswith("this drive determines 2 fibre elevations and 1 fibre "
                                                           "height (fibres that see")
    # an extrinsic axis: what would sharpen it follows from the drive's manoeuvres (no slope: its lever arm's z)
    assert verdict([], {}, TURNING, ["extrinsic.lever_arm_z_m"]) == (
        "this drive determines the lever arm z (a drive with slopes or banked turns (the vehicle rolling or "
        "pitching) would sharpen it) more coarsely than required: its fitted value kept")
    # with trajectory corrections estimated (their gauge named) they take up the lever arm: a survey decides it
    line = verdict(["trajectory.common_translation"], {}, TURNING, ["extrinsic.lever_arm_x_m", "extrinsic.pitch_deg"])
    assert line == ("this drive determines the lever arm x (a surveyed lever arm as the nominal, its sigma in "
                    "priors.extrinsic_lever_arm_m, would sharpen it) and the boresight pitch (facades or poles beside "
                    "the road, not only flat ground, would sharpen it) more coarsely than required: their fitted "
                    "values kept")


def test_the_report_marks_an_imprecise_value_apart_from_an_unobservable_and_a_held_one():
    from graphcal.report.tables import parameter_rows

    rows = [{"fibre": f, "d_range_m": 0.01, "d_azimuth_deg": 0.02, "d_elevation_deg": 0.03,
             "h_z_m": None if f == 2 else 0.004,
             "sigma": {"d_range_m": 0.001, "d_azimuth_deg": 0.002, "d_elevation_deg": 0.02,
                       "h_z_m": None if f == 2 else 0.001}} for f in range(3)]
    calibration = {"intrinsics": rows, "extrinsic": {"lever_arm_m": [0, 0, 0], "boresight_deg": [0, 0, 0]},
                   "unobservable": ["fibre_0.d_range_m", "fibre_2.h_z_m"],
                   "imprecise": {"fibre_1.d_elevation_deg": "imprecise: determined to 0.02 deg ..."}}
    (_, _, intrinsics), = [table for table in parameter_rows(calibration) if table[0].startswith("Intrinsic")]
    assert intrinsics[0][1] == "1 ± 0.1 (unobservable)"  # cm
    assert intrinsics[1][3] == "0.03 ± 0.02 (imprecise)" and intrinsics[1][1] == "1 ± 0.1"
    assert intrinsics[2][4] == "held at nominal"
    calibration["extrinsic"]["sigma"] = {"lever_arm_m": [0.001, 0.001, 0.02], "boresight_deg": [0.001, 0.001, 0.001]}
    calibration["imprecise"]["extrinsic.lever_arm_z_m"] = "imprecise: determined to 2 cm ..."
    (_, _, extrinsic), = [table for table in parameter_rows(calibration) if table[0].startswith("Extrinsic")]
    assert [row[1].endswith(" (imprecise)") for row in extrinsic] == [False] * 5 + [True]
