"""Evaluation against truth: the rigid motion of unobservable parameters is a gauge, removed
before the gauge-free cloud distance, and not counted in the lever-arm error; a long recording is read
only at the sampled returns, its true cloud subsampled."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from graphcal.calibration import evaluate as evaluation
from graphcal.calibration.evaluate import nominal_calibration, remove_gauge
from conftest import city_drive


@pytest.fixture
def truth():
    return np.random.default_rng(3).uniform(-20, 20, (2000, 3))


@pytest.mark.parametrize("names", [("trajectory.common_translation",), ("extrinsic.lever_arm_z_m",)])
def test_an_unobservable_translation_is_removed(truth, names):
    shifted = truth + [0.1, -0.2, 0.8]
    np.testing.assert_allclose(remove_gauge(shifted, truth, names), truth, atol=1e-12)


@pytest.mark.parametrize("names", [("trajectory.common_translation", "trajectory.common_rotation"),
                                   ("extrinsic.lever_arm_x_m", "extrinsic.roll_deg")])
def test_an_unobservable_rigid_turn_is_removed(truth, names):
    moved = Rotation.from_euler("xyz", [2.0, -1.0, 3.0], degrees=True).apply(truth) + [0.3, 0.0, -0.5]
    np.testing.assert_allclose(remove_gauge(moved, truth, names), truth, atol=1e-9)


def test_observable_errors_stay(truth):
    shifted = truth + [0.0, 0.0, 0.8]
    assert remove_gauge(shifted, truth, ("fibre_3.d_range_m",)) is shifted
    turned = Rotation.from_euler("z", 2.0, degrees=True).apply(truth)
    kept = remove_gauge(turned, truth, ("extrinsic.lever_arm_z_m",))  # a translation gauge leaves the turn
    assert np.abs(kept - truth).max() > 0.1


@pytest.fixture(scope="module")
def saved_drive(tmp_path_factory):
    return city_drive(tmp_path_factory.mktemp("drive") / "city", 3.0, 0.02, 4)


def test_true_points_are_read_at_the_rows_asked(saved_drive):
    rows = np.sort(np.random.default_rng(1).choice(len(saved_drive.points), 5000, replace=False))
    np.testing.assert_array_equal(saved_drive.truth.world_points_at(rows), saved_drive.truth.world_points()[rows])


def test_a_subsampled_true_cloud_only_lengthens_the_distances(saved_drive, monkeypatch):
    calibration = nominal_calibration(saved_drive)
    whole = evaluation.evaluate(calibration, saved_drive, max_points=3000)
    monkeypatch.setattr(evaluation, "REFERENCE_MAX_POINTS", len(saved_drive.points) // 4)
    sub = evaluation.evaluate(calibration, saved_drive, max_points=3000)
    np.testing.assert_array_equal(sub.intrinsic_rms_after, whole.intrinsic_rms_after)
    np.testing.assert_allclose(sub.common_offset_m, whole.common_offset_m)  # against each sampled return's own truth
    # the nearest of a subset is never nearer than the nearest of the whole cloud
    assert sub.cloud_after.median >= whole.cloud_after.median and sub.cloud_after.max >= whole.cloud_after.max


def _evaluation(before_m: float, after_m: float, gauge_free_m: float) -> evaluation.Evaluation:
    def stats(mean):
        return evaluation.DistanceStats(mean, mean, mean, mean)

    return evaluation.Evaluation(np.zeros(4), np.zeros(4), (0.0, 0.0), (0.0, 0.0), stats(before_m), stats(after_m),
                                 (1.0, 1.0), np.zeros(3), stats(gauge_free_m))


def test_the_cloud_line_leads_with_the_distance_once_the_gauge_is_fitted_out():
    # a drive whose common translation slid 24 cm: as placed the cloud reads further from the truth than before
    line = _evaluation(0.234, 0.248, 0.0062).cloud_line()
    assert line.index("23.4 cm before") < line.index("0.62 cm after") < line.index("(24.8 cm as placed)")
    assert _evaluation(0.234, 0.0062, 0.0061).cloud_line().endswith("23.4 cm before, 0.62 cm after")
