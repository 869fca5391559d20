"""The beam-origin term of the sensor model (Ouster lidar_origin_to_beam_origin_mm): Jacobian, inverse, folding."""

import numpy as np
import pytest

from factors.spherical import FactoryTerms, beam_directions, beam_rays, from_xyz, to_xyz, to_xyz_with_jacobian
from graphcal.common.errors import RecordingError
from graphcal.recording.sensor import SensorModel

RNG = np.random.default_rng(27)
N = 200


def _factory(beam_origin_m=0.015806, with_offsets=True) -> FactoryTerms:
    k = 1.0 if with_offsets else 0.0
    return FactoryTerms(elevation_rad=RNG.uniform(-0.4, 0.4, N), azimuth_offset_rad=RNG.uniform(-0.08, 0.08, N),
                        range_offset_m=k * RNG.normal(0, 0.02, N), vertical_offset_m=k * RNG.normal(0, 0.1, N),
                        horizontal_offset_m=k * RNG.normal(0, 0.03, N), height_offset_m=k * RNG.normal(0, 0.01, N),
                        beam_origin_m=beam_origin_m)


def _returns():
    offsets = np.column_stack([RNG.normal(0, 0.02, N), RNG.normal(0, 0.003, N), RNG.normal(0, 0.003, N),
                               RNG.normal(0, 0.01, N)])
    return RNG.uniform(0.5, 80.0, N), RNG.uniform(0, 2 * np.pi, N), offsets


def test_jacobian_matches_finite_differences_with_a_beam_origin():
    range_m, azimuth, offsets = _returns()
    factory = _factory()
    _, J = to_xyz_with_jacobian(range_m, azimuth, factory, offsets)
    steps = (1e-6, 1e-8, 1e-8, 1e-6)
    for k, step in enumerate(steps):
        plus, minus = offsets.copy(), offsets.copy()
        plus[:, k] += step
        minus[:, k] -= step
        numeric = (to_xyz(range_m, azimuth, factory, plus) - to_xyz(range_m, azimuth, factory, minus)) / (2 * step)
        np.testing.assert_allclose(J[..., k], numeric, atol=1e-6)


def test_matches_the_ouster_documented_formula():
    """Ouster sensor docs: theta_e = 2 pi (1 - m / W), theta_a = -2 pi az / 360, phi = 2 pi alt / 360,
    x = (r - n) cos(theta_e + theta_a) cos(phi) + n cos(theta_e), y = ... sin ..., z = (r - n) sin(phi)."""
    width, n_m = 1024, 0.027670
    column = RNG.integers(0, width, N)
    altitude_deg, azimuth_deg = RNG.uniform(-45, 45, N), RNG.uniform(-12, 12, N)
    r = RNG.uniform(0.3, 120.0, N)
    theta_e = 2 * np.pi * (1 - column / width)
    theta_a = -2 * np.pi * azimuth_deg / 360
    phi = 2 * np.pi * altitude_deg / 360
    documented = np.column_stack([(r - n_m) * np.cos(theta_e + theta_a) * np.cos(phi) + n_m * np.cos(theta_e),
                                  (r - n_m) * np.sin(theta_e + theta_a) * np.cos(phi) + n_m * np.sin(theta_e),
                                  (r - n_m) * np.sin(phi)])
    factory = FactoryTerms(np.radians(altitude_deg), azimuth_offset_rad=np.radians(azimuth_deg), beam_origin_m=n_m)
    ours = to_xyz(r, 2 * np.pi * column / width, factory, np.zeros((N, 4)))
    np.testing.assert_allclose(ours, documented, atol=1e-9)


@pytest.mark.parametrize("with_offsets", [False, True])
def test_from_xyz_inverts_to_xyz_with_a_beam_origin(with_offsets):
    range_m, azimuth, offsets = _returns()
    factory = _factory(with_offsets=with_offsets)
    xyz = to_xyz(range_m, azimuth, factory, offsets)
    back_range, back_azimuth, off_cone = from_xyz(xyz, factory, offsets)
    np.testing.assert_allclose(back_range, range_m, atol=1e-9)
    np.testing.assert_allclose(np.angle(np.exp(1j * (back_azimuth - azimuth))), 0.0, atol=1e-9)
    np.testing.assert_allclose(off_cone, 0.0, atol=1e-9)


def test_beam_rays_start_at_the_beam_origin():
    range_m, azimuth, offsets = _returns()
    factory = _factory(with_offsets=False)
    origin, direction = beam_rays(azimuth, factory, offsets)
    B = factory.beam_origin_m
    np.testing.assert_allclose(origin, np.column_stack([B * np.cos(azimuth), -B * np.sin(azimuth), offsets[:, 3]]),
                               atol=1e-12)
    corrected = range_m + offsets[:, 0] - B
    np.testing.assert_allclose(origin + corrected[:, None] * direction, to_xyz(range_m, azimuth, factory, offsets),
                               atol=1e-9)


def test_beam_directions_are_the_unit_derivative_along_the_range():
    """With every factory term and offset set: the direction is to_xyz's change per metre of range (eq. 4.2 is
    linear in the range), of unit length."""
    range_m, azimuth, offsets = _returns()
    factory = _factory()
    direction = beam_directions(azimuth, factory, offsets)
    numeric = to_xyz(range_m + 1.0, azimuth, factory, offsets) - to_xyz(range_m, azimuth, factory, offsets)
    np.testing.assert_allclose(direction, numeric, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(direction, axis=1), 1.0, atol=1e-12)


def _ouster_like(beam_origin_m=0.015806) -> SensorModel:
    n = 8
    return SensorModel(model="OS-1-128", rotation_hz=10.0, reference_fibre=4,
                       elevation_deg=np.linspace(20.0, -21.0, n), azimuth_offset_deg=np.tile([4.2, 1.4, -1.4, -4.2], 2),
                       range_offset_m=np.zeros(n), vertical_offset_m=np.zeros(n), horizontal_offset_m=np.zeros(n),
                       height_offset_m=np.zeros(n), beam_origin_m=beam_origin_m)


def test_a_calibration_folds_exactly_into_a_model_with_a_beam_origin():
    sensor = _ouster_like()
    offsets = np.column_stack([RNG.normal(0, 0.02, 8), RNG.normal(0, 0.003, 8), RNG.normal(0, 0.003, 8),
                               RNG.normal(0, 0.01, 8)])
    fibre = RNG.integers(0, 8, N)
    range_m, azimuth = RNG.uniform(0.5, 60, N), RNG.uniform(0, 2 * np.pi, N)
    folded = sensor.with_offsets(offsets)
    np.testing.assert_allclose(folded.to_xyz(fibre, range_m, azimuth), sensor.to_xyz(fibre, range_m, azimuth, offsets),
                               atol=1e-12)


def test_sensor_yaml_keeps_the_beam_origin():
    sensor = _ouster_like()
    data = sensor.to_dict()
    assert data["beam_origin_m"] == pytest.approx(0.015806)
    again = SensorModel.from_dict(data)
    assert again.beam_origin_m == pytest.approx(0.015806)
    fibre = np.arange(8)
    np.testing.assert_array_equal(again.to_xyz(fibre, np.full(8, 5.0), np.zeros(8)),
                                  sensor.to_xyz(fibre, np.full(8, 5.0), np.zeros(8)))
    assert "beam_origin_m" not in _ouster_like(0.0).to_dict()
    with pytest.raises(RecordingError, match="beam_origin_m"):
        SensorModel.from_dict(data | {"beam_origin_m": "15 mm"})
