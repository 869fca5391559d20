"""The azimuth-halves check of a static calibration (docs/reference/math.md "A static sensor") on the real
static HDL-32E recording (VeloView's monterey pcap) with one half's ground changed: heights that fit one
half of the scene are not returned. The passing branch: test_static_calibration.py."""

import numpy as np
import pytest

import graphcal
from conftest import HEIGHTS_FREE, MONTEREY_SEED
from graphcal.calibration.result import HALVES_FILE
from graphcal.common.yamlfile import read_yaml
from graphcal.recording.points import PointTable
from graphcal.report.html import write_report


def one_half_lowered(recording):
    """The recording with the ground fibres' (elevation below -10 deg) ranges in the azimuth half [0, 180)
    deg lengthened by 15 cm x (-10 deg - elevation) / 20 deg (the ground there seen lower, more so further
    out): that half's ground is not the other's."""
    columns = recording.points.read()
    elevation = recording.sensor.elevation_deg[columns["fibre"]]
    lowered = (np.mod(columns["azimuth"], 2 * np.pi) < np.pi) & (elevation < -10)
    columns["range"] = columns["range"] + np.where(lowered, 0.15 * (-10 - elevation) / 20, 0.0)
    return recording.with_points(PointTable.from_arrays(**columns))


def test_heights_that_fit_one_half_of_the_scene_are_not_returned(monterey_recording, tmp_path):
    """With one half's ground lowered, the ground fibres' heights are determined by each azimuth half
    alone, but the fit on one half raises J on the other half's pairs: they follow the ground each
    half sees, not the sensor. They are held and named, so the calibration is the nominal one, and
    the report shows the evidence."""
    recording = one_half_lowered(monterey_recording)
    result = graphcal.calibrate(recording, graphcal.CalibrationConfig(mode="intrinsic", seed=MONTEREY_SEED,
                                                                      static={"hold": HEIGHTS_FREE}), quiet=True)
    halves = result.halves
    assert not halves["passed"]
    held_out = [fold["held_out_energy_cm2"] for fold in halves["folds"]]
    assert any(j["after"] > j["before"] for j in held_out)
    tried = set(halves["folds"][0]["estimates"])
    assert tried and tried <= set(halves["held"]) and tried <= set(result.unobservable)
    fibres = [f for f in range(recording.sensor.n_fibres) if f != recording.sensor.reference_fibre]
    assert {f"fibre_{f}.h_z_m" for f in fibres} <= set(result.unobservable)
    np.testing.assert_allclose(result.calibration.estimate.offsets, 0.0, atol=1e-6)  # the nominal model
    start, end = result.energy_cm2
    assert end == pytest.approx(start, rel=1e-4)
    result.save(tmp_path)
    assert read_yaml(tmp_path / HALVES_FILE) == halves
    page = write_report(tmp_path).read_text()
    assert "the azimuth-halves check" in page and "failed: a half" in page
