"""The first real calibration: the static HDL-32E recording (VeloView's monterey pcap) is calibrated
on what a static head determines, and the rest is named (docs/reference/math.md "A static sensor")."""

from pathlib import Path

import numpy as np
import pytest

import graphcal
from graphcal.calibration.result import HALVES_FILE
from graphcal.importers.velodyne_pcap import import_pcap
from graphcal.recording.points import PointTable
from graphcal.report.html import write_report
from graphcal.common.yamlfile import read_yaml

MONTEREY = Path(__file__).resolve().parents[2] / "shared/data/real/veloview_hdl32e_vlp16_pcap/monterey-first-100-packets.pcap"


# With the nearest return of a neighbouring fibre, the halves check on the ground fibres' heights
# passed or failed with the random draw of the pairs (session 10); with the line-of-sight choice of
# m (graphcal/calibration/association.py) it passed on every seed tried (0 to 15, session 11); the suite runs seed 0.
# The failing branch is tested on the recording with one half's ground changed.
SEED = 0


@pytest.fixture(scope="module")
def imported():
    if not MONTEREY.is_file():
        pytest.skip("shared real data absent")
    return import_pcap(MONTEREY, quiet=True)


# by default a static sensor's heights are held too; the halves check runs on them once they are freed
HEIGHTS_FREE = ("fibre_*.d_elevation_deg", "fibre_*.d_range_m", "fibre_*.d_azimuth_deg")


@pytest.fixture(scope="module")
def monterey(imported):
    config = graphcal.CalibrationConfig(mode="intrinsic", seed=SEED, static={"hold": HEIGHTS_FREE})
    return imported, graphcal.calibrate(imported, config, quiet=True)


def one_half_lowered(recording):
    """The recording with the ground fibres' (elevation below -10 deg) ranges in the azimuth half [0, 180)
    deg lengthened by 15 cm x (-10 deg - elevation) / 20 deg (the ground there seen lower, more so further
    out): that half's ground is not the other's."""
    columns = recording.points.read()
    elevation = recording.sensor.elevation_deg[columns["fibre"]]
    lowered = (np.mod(columns["azimuth"], 2 * np.pi) < np.pi) & (elevation < -10)
    columns["range"] = columns["range"] + np.where(lowered, 0.15 * (-10 - elevation) / 20, 0.0)
    return recording.with_points(PointTable.from_arrays(**columns))


def test_a_static_recording_is_not_calibrated_by_default(imported):
    """Every intrinsic of a static head is held and named: the calibration is the nominal one."""
    result = graphcal.calibrate(imported, graphcal.CalibrationConfig(mode="intrinsic"), quiet=True)
    fibres = [f for f in range(imported.sensor.n_fibres) if f != imported.sensor.reference_fibre]
    for name in ("d_range_m", "d_azimuth_deg", "d_elevation_deg", "h_z_m"):
        assert {f"fibre_{f}.{name}" for f in fibres} <= set(result.unobservable)
    np.testing.assert_allclose(result.calibration.estimate.offsets, 0.0, atol=1e-9)
    assert result.halves is None  # nothing left free to check: no halves check, no halves table in the report


def test_the_static_recording_is_fitted_on_fixed_pairs_with_what_it_cannot_see_named(monterey):
    recording, result = monterey
    history = result.history
    # the pairs are made once: the energy cannot fall by dropping pairs as the fibres move
    assert len({row["pairs"] for row in history}) == 1 and history[0]["phase"] == "fine"
    assert history[-1]["energy_after_cm2"] <= history[0]["energy_cm2"]
    unobservable = set(result.unobservable)
    fibres = [f for f in range(recording.sensor.n_fibres) if f != recording.sensor.reference_fibre]
    for name in ("d_range_m", "d_azimuth_deg", "d_elevation_deg"):
        assert {f"fibre_{f}.{name}" for f in fibres} <= unobservable
    assert {"extrinsic.yaw_deg", "trajectory.common_translation"} <= unobservable


def test_heights_that_fit_one_half_of_the_scene_are_not_returned(imported, tmp_path):
    """With one half's ground lowered, the ground fibres' heights are determined by each azimuth half
    alone, but the fit on one half raises J on the other half's pairs: they follow the ground each
    half sees, not the sensor. They are held and named, so the calibration is the nominal one, and
    the report shows the evidence."""
    recording = one_half_lowered(imported)
    result = graphcal.calibrate(recording, graphcal.CalibrationConfig(mode="intrinsic", seed=SEED,
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


def test_heights_that_fit_the_other_half_on_every_draw_are_returned(monterey):
    """Every half's fit (three draws of the pairs, two halves each) lowers J on the other half's pairs,
    and the heights it fitted are the calibration, with sigmas, and lower J."""
    result = monterey[1]
    halves = result.halves
    assert halves["passed"] and len(halves["folds"]) == 6
    assert all(fold["held_out_energy_cm2"]["after"] < fold["held_out_energy_cm2"]["before"] for fold in halves["folds"])
    kept = set(halves["folds"][0]["estimates"])
    assert kept and not kept & set(result.unobservable) and all(name.endswith(".h_z_m") for name in kept)
    for name in kept:
        fibre = int(name.split(".")[0].removeprefix("fibre_"))
        value_m, sigma_m = result.calibration.estimate.offsets[fibre, 3], result.uncertainty.intrinsics[fibre, 3]
        fits = [fold["estimates"][name] for fold in halves["folds"]]
        assert min(fits) - 0.01 <= value_m <= max(fits) + 0.01 and 0 < sigma_m < 0.01  # m
    start, end = result.energy_cm2
    assert end < 0.9 * start
