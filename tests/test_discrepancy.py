"""Generic discrepancy models (factors/discrepancy.py): the bases span smooth shapes but never a constant, a
name rebuilds its model, the curve and its band follow from the coefficients, and the elevation channel moves a
return as the fibre's elevation does (eq. 4.2). Their block-factor Jacobians are checked against finite
differences in tests/test_effects_factor.py."""

import numpy as np
import pytest

from factors.channels import Channels, Context, Motion, perturbed
from factors.discrepancy import Discrepancy, regressor_values
from factors.spherical import to_xyz
from factors.world_point import Returns
from graphcal.recording.sensor import sensor_from_catalog

MODELS = [Discrepancy.uniform("range", "intensity", 6, 5.0, 250.0), Discrepancy.uniform("azimuth", "azimuth", 6, 0.0, 360.0),
          Discrepancy.uniform("elevation", "range", 8, 3.0, 60.0), Discrepancy.uniform("time", "fibre", 31, 0.0, 31.0)]


@pytest.mark.parametrize("model", MODELS, ids=lambda m: m.name)
def test_a_name_rebuilds_its_model(model):
    assert Discrepancy.parse(model.name) == model


@pytest.mark.parametrize("model", MODELS, ids=lambda m: m.name)
def test_no_basis_spans_a_constant(model):
    """A constant error of a channel is an ordinary parameter's: the best fit of one leaves it whole."""
    B = model.design(model.grid())
    constant = np.ones(len(B))
    fitted = B @ np.linalg.lstsq(B, constant, rcond=None)[0]
    assert np.linalg.norm(constant - fitted) > 0.99 * np.linalg.norm(constant)
    assert np.linalg.matrix_rank(B) == model.size  # and every column counts


def test_a_smooth_shape_is_spanned_with_its_mean_removed():
    """Range walk: a decaying curve of the intensity, recovered (mean removed) by 8 cubic B-spline columns."""
    model = Discrepancy.uniform("range", "intensity", 8, 0.0, 255.0)
    x = np.linspace(0, 255, 2000)
    truth = 0.03 * np.exp(-x / 40.0)
    B = model.design(x)
    theta = np.linalg.lstsq(B, truth - truth.mean(), rcond=None)[0]
    error = (B @ theta) - (truth - truth.mean())
    error -= error.mean()
    assert np.sqrt(np.mean(error ** 2)) < 0.02 * np.sqrt(np.mean((truth - truth.mean()) ** 2))
    curve = model.curve(theta, np.eye(model.size) * 1e-8)
    assert curve["y"].shape == curve["x"].shape == curve["sigma"].shape
    assert model.magnitude_of(theta) == pytest.approx(np.ptp(curve["y"]))
    assert model.magnitude_of(theta) == pytest.approx(np.ptp(truth), rel=0.05)


def test_angles_are_reported_in_degrees_and_signs_follow_the_contract():
    """curve.y is true minus modelled angle in degrees; a range curve is measured minus true range, so its channel
    (what restores the truth) is its negative."""
    rng = np.random.default_rng(4)
    n = 50
    context = Context(rng.uniform(3, 40, n), rng.uniform(0, 2 * np.pi, n), rng.integers(0, 4, n), 4,
                      np.zeros(n), np.zeros(n), np.ones(n), np.zeros((n, 3)), intensity=rng.uniform(0, 255, n))
    azimuth = Discrepancy.uniform("azimuth", "azimuth", 2, 0.0, 360.0)
    theta = np.array([np.radians(0.05), 0.0])  # 0.05 deg sin(azimuth)
    np.testing.assert_allclose(azimuth.basis(context).azimuth @ theta, np.radians(0.05) * np.sin(context.azimuth_rad))
    assert azimuth.magnitude_of(theta) == pytest.approx(0.1, rel=1e-3)  # peak to peak, deg
    ranged = Discrepancy.uniform("range", "intensity", 4, 0.0, 255.0)
    theta = rng.normal(0, 0.01, 4)
    x = regressor_values(context, "intensity")
    np.testing.assert_allclose(ranged.basis(context).range @ theta, -(ranged.design(x) @ theta))


def test_the_elevation_channel_moves_a_return_as_its_fibre_elevation_does():
    rng = np.random.default_rng(5)
    sensor = sensor_from_catalog("HDL-32E")
    n = 100
    fibre = rng.integers(0, sensor.n_fibres, n)
    returns = Returns(range_m=rng.uniform(3, 40, n), azimuth_rad=rng.uniform(0, 2 * np.pi, n),
                      factory=sensor.factory_terms(fibre), R_nav=np.broadcast_to(np.eye(3), (n, 3, 3)),
                      X_nav=np.zeros((n, 3)), alpha=np.zeros(n))
    d_phi = rng.normal(0, 0.01, n)
    zero, zero3 = np.zeros(n), np.zeros((n, 3))
    channels = Channels(range=zero, azimuth=zero, elevation=d_phi, horizontal=zero, time=zero, heading=zero,
                        body=zero3, position=zero3)
    moved = perturbed(returns, Motion(zero3, zero3), channels)
    offsets = np.zeros((n, 4))
    by_offset = to_xyz(returns.range_m, returns.azimuth_rad, returns.factory, np.column_stack([zero, zero, d_phi, zero]))
    np.testing.assert_allclose(to_xyz(moved.range_m, moved.azimuth_rad, moved.factory, offsets), by_offset, atol=1e-12)
    assert not np.allclose(by_offset, to_xyz(returns.range_m, returns.azimuth_rad, returns.factory, offsets), atol=1e-6)


def test_a_regressor_the_returns_lack_is_reported():
    n = 10
    context = Context(np.ones(n), np.zeros(n), np.zeros(n, int), 2, np.zeros(n), np.zeros(n), np.ones(n),
                      np.zeros((n, 3)))
    assert regressor_values(context, "intensity") is None
    with pytest.raises(ValueError, match="no intensity"):
        Discrepancy.uniform("range", "intensity", 4, 0.0, 1.0).basis(context)
