"""Evaluation against truth: the rigid motion of unobservable parameters is a gauge, removed
before the gauge-free cloud distance, and not counted in the lever-arm error."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from graphcal.calibration.evaluate import remove_gauge


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
