"""The first real calibration: the static HDL-32E recording (VeloView's monterey pcap) is calibrated
on what a static head determines, and the rest is named (docs/reference/math.md "A static sensor")."""

import numpy as np
import pytest

import graphcal
from conftest import HEIGHTS_FREE, MONTEREY_SEED


@pytest.fixture(scope="module")
def monterey(monterey_recording):
    config = graphcal.CalibrationConfig(mode="intrinsic", seed=MONTEREY_SEED, static={"hold": HEIGHTS_FREE})
    return monterey_recording, graphcal.calibrate(monterey_recording, config, quiet=True)


def test_a_static_recording_is_not_calibrated_by_default(monterey_recording):
    """Every intrinsic of a static head is held and named: the calibration is the nominal one."""
    result = graphcal.calibrate(monterey_recording, graphcal.CalibrationConfig(mode="intrinsic"), quiet=True)
    fibres = [f for f in range(monterey_recording.sensor.n_fibres) if f != monterey_recording.sensor.reference_fibre]
    for name in ("d_range_m", "d_azimuth_deg", "d_elevation_deg", "h_z_m"):
        assert {f"fibre_{f}.{name}" for f in fibres} <= set(result.unobservable)
    reference = monterey_recording.sensor.reference_fibre  # its range and elevation too, its gauges held unnamed
    assert {f"fibre_{reference}.d_range_m", f"fibre_{reference}.d_elevation_deg"} <= set(result.unobservable)
    np.testing.assert_allclose(result.calibration.estimate.offsets, 0.0, atol=1e-9)
    assert result.verdict.startswith("static sensor: the extrinsic and the trajectory are unobservable; "
                                     f"{len(fibres) * 4 + 2} intrinsic parameters held")
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
