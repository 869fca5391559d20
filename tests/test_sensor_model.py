"""Sensor model eq. 4.2: formula, analytic Jacobians vs finite differences, inverse, catalogue."""

from pathlib import Path

import numpy as np
import pytest
import yaml

from factors.spherical import (
    FactoryTerms,
    beam_rays,
    from_xyz,
    to_xyz,
    to_xyz_with_jacobian,
)
from graphcal.recording.sensor import CATALOG, SensorModel, sensor_from_catalog

SHARED_CALIBRATION = Path(__file__).resolve().parents[2] / "shared/data/real/nebula_velodyne_rosbag2/calibration"


def _returns(sensor: SensorModel, n=2000, seed=0):
    rng = np.random.default_rng(seed)
    fibre = rng.integers(0, sensor.n_fibres, n)
    range_m = rng.uniform(1.0, 80.0, n)
    azimuth = rng.uniform(0.0, 2 * np.pi, n)
    offsets = np.column_stack([rng.uniform(-0.1, 0.1, sensor.n_fibres), np.radians(rng.uniform(-3, 3, sensor.n_fibres)),
                               np.radians(rng.uniform(-3, 3, sensor.n_fibres)), rng.uniform(-0.1, 0.1, sensor.n_fibres)])
    return fibre, range_m, azimuth, offsets


def test_eq_4_2_written_out():
    """With no factory terms the model is exactly eq. 4.2 of seed 000."""
    sensor = sensor_from_catalog("HDL-32E")
    fibre, rho, theta, offsets = _returns(sensor)
    d_rho, d_theta, d_phi, h_z = offsets[fibre].T
    phi = np.radians(sensor.elevation_deg[fibre])
    expected = np.column_stack([(rho + d_rho) * np.cos(theta + d_theta) * np.cos(phi + d_phi),
                                -(rho + d_rho) * np.sin(theta + d_theta) * np.cos(phi + d_phi),
                                (rho + d_rho) * np.sin(phi + d_phi) + h_z])
    np.testing.assert_allclose(sensor.to_xyz(fibre, rho, theta, offsets), expected, rtol=0, atol=1e-12)


@pytest.mark.parametrize("model", sorted(CATALOG))
def test_jacobian_matches_finite_differences(model):
    sensor = sensor_from_catalog(model)
    fibre, rho, theta, offsets = _returns(sensor, n=500)
    _, jacobian = sensor.to_xyz_with_jacobian(fibre, rho, theta, offsets)
    step = np.array([1e-6, 1e-8, 1e-8, 1e-6])
    for k in range(4):
        plus, minus = offsets.copy(), offsets.copy()
        plus[:, k] += step[k]
        minus[:, k] -= step[k]
        numeric = (sensor.to_xyz(fibre, rho, theta, plus) - sensor.to_xyz(fibre, rho, theta, minus)) / (2 * step[k])
        np.testing.assert_allclose(jacobian[:, :, k], numeric, atol=1e-6 * max(1.0, np.abs(numeric).max()))


@pytest.mark.parametrize("model", sorted(CATALOG))
def test_inverse_round_trip(model):
    sensor = sensor_from_catalog(model)
    fibre, rho, theta, offsets = _returns(sensor)
    xyz = sensor.to_xyz(fibre, rho, theta, offsets)
    range_back, azimuth_back, off_cone = sensor.from_xyz(fibre, xyz, offsets)
    np.testing.assert_allclose(range_back, rho, atol=1e-9)
    np.testing.assert_allclose(np.angle(np.exp(1j * (azimuth_back - theta))), 0.0, atol=1e-11)
    np.testing.assert_allclose(off_cone, 0.0, atol=1e-9)


def test_inverse_reports_points_off_the_cone():
    sensor = sensor_from_catalog("HDL-32E")
    fibre, rho, theta, _ = _returns(sensor, n=100)
    xyz = sensor.to_xyz(fibre, rho, theta) + np.array([0.0, 0.0, 0.05])
    _, _, off_cone = sensor.from_xyz(fibre, xyz)
    np.testing.assert_allclose(off_cone, 0.05 * np.cos(np.radians(sensor.elevation_deg[fibre])), atol=1e-9)


def test_beam_rays_parametrise_the_model():
    sensor = sensor_from_catalog("HDL-64E")
    fibre, rho, theta, offsets = _returns(sensor)
    factory = sensor.factory_terms(fibre)
    origin, direction = beam_rays(theta, factory, offsets[fibre])
    np.testing.assert_allclose(np.linalg.norm(direction, axis=1), 1.0, atol=1e-12)
    r = rho + offsets[fibre, 0] + factory.range_offset_m
    np.testing.assert_allclose(origin + r[:, None] * direction, to_xyz(rho, theta, factory, offsets[fibre]), atol=1e-9)


def test_hdl64e_matches_the_velodyne_driver_formula():
    """Independent check: the ROS velodyne_pointcloud raw-data formula (rawdata.cc), with
    rot_correction = -azimuth_offset and the driver's own x/y swap."""
    sensor = sensor_from_catalog("HDL-64E")
    fibre, rho, theta, _ = _returns(sensor)
    rot = theta - (-np.radians(sensor.azimuth_offset_deg[fibre]))
    vert = np.radians(sensor.elevation_deg[fibre])
    distance = rho + sensor.range_offset_m[fibre]
    v_off, h_off = sensor.vertical_offset_m[fibre], sensor.horizontal_offset_m[fibre]
    xy_distance = distance * np.cos(vert) - v_off * np.sin(vert)
    xx = xy_distance * np.sin(rot) - h_off * np.cos(rot)
    yy = xy_distance * np.cos(rot) + h_off * np.sin(rot)
    expected = np.column_stack([yy, -xx, distance * np.sin(vert) + v_off * np.cos(vert)])
    np.testing.assert_allclose(sensor.to_xyz(fibre, rho, theta), expected, atol=1e-9)


def test_catalogue_tables():
    hdl32 = sensor_from_catalog("HDL-32E")
    assert hdl32.n_fibres == 32 and hdl32.reference_fibre == 15 and hdl32.elevation_deg[15] == 0.0
    assert hdl32.elevation_deg.min() == -30.67 and hdl32.elevation_deg.max() == 10.67
    np.testing.assert_allclose(np.diff(np.sort(hdl32.elevation_deg)), 4 / 3, atol=0.011)
    assert np.all(hdl32.vertical_offset_m == 0) and np.all(hdl32.horizontal_offset_m == 0)
    vlp16 = sensor_from_catalog("VLP-16")
    np.testing.assert_array_equal(np.sort(vlp16.elevation_deg), np.arange(-15, 16, 2))
    hdl64 = sensor_from_catalog("HDL-64E", rotation_hz=15.0)
    assert hdl64.n_fibres == 64 and hdl64.rotation_hz == 15.0
    assert np.all(hdl64.vertical_offset_m > 0) and np.all(np.abs(hdl64.horizontal_offset_m) > 0)
    with pytest.raises(KeyError, match="HDL-32E"):
        sensor_from_catalog("HDL-16")


@pytest.mark.skipif(not SHARED_CALIBRATION.is_dir(), reason="shared real calibration files absent")
def test_hdl32_elevations_match_the_factory_file():
    lasers = yaml.safe_load((SHARED_CALIBRATION / "HDL32.yaml").read_text())["lasers"]
    factory = np.degrees([laser["vert_correction"] for laser in sorted(lasers, key=lambda l: l["laser_id"])])
    np.testing.assert_allclose(sensor_from_catalog("HDL-32E").elevation_deg, factory, atol=0.006)


@pytest.mark.parametrize("model", sorted(CATALOG))
def test_sensor_yaml_round_trip(model):
    sensor = sensor_from_catalog(model)
    back = SensorModel.from_dict(yaml.safe_load(yaml.safe_dump(sensor.to_dict())))
    for name in ("elevation_deg", "azimuth_offset_deg", "range_offset_m", "vertical_offset_m", "horizontal_offset_m"):
        np.testing.assert_array_equal(getattr(back, name), getattr(sensor, name))
    assert (back.model, back.rotation_hz, back.reference_fibre) == (sensor.model, sensor.rotation_hz,
                                                                      sensor.reference_fibre)
    assert back.timing == sensor.timing


def test_factory_terms_default_to_eq_4_1():
    xyz = to_xyz(np.array([10.0]), np.array([np.pi / 2]), FactoryTerms(np.array([0.0])), np.zeros((1, 4)))
    np.testing.assert_allclose(xyz, [[0.0, -10.0, 0.0]], atol=1e-12)  # clockwise azimuth: y = -sin
    _, jacobian = to_xyz_with_jacobian(np.array([10.0]), np.array([0.0]), FactoryTerms(np.array([0.0])),
                                       np.zeros((1, 4)))
    np.testing.assert_allclose(jacobian[0], [[1, 0, 0, 0], [0, -10, 0, 0], [0, 0, 10, 1]], atol=1e-12)
    assert from_xyz(np.array([[0.0, -10.0, 0.0]]), FactoryTerms(np.array([0.0])), np.zeros((1, 4)))[1][0] == \
        pytest.approx(np.pi / 2)


def test_a_calibration_folds_into_the_factory_terms_exactly():
    """With no vertical or horizontal laser offset, offsets (d_rho, d_theta, d_phi, Hz) folded into the
    factory terms (range, azimuth and height offsets, elevation) give the same points: a calibrated
    model can be the next calibration's nominal (sensor.yaml's height_offset_m holds Hz)."""
    from factors.spherical import FactoryTerms, to_xyz

    rng = np.random.default_rng(6)
    n = 500
    elevation = np.radians(rng.uniform(-30, 10, n))
    offsets = np.column_stack([rng.normal(0, 0.03, n), rng.normal(0, 0.005, n), rng.normal(0, 0.005, n),
                               rng.normal(0, 0.03, n)])
    range_m, azimuth = rng.uniform(2, 60, n), rng.uniform(0, 2 * np.pi, n)
    calibrated = to_xyz(range_m, azimuth, FactoryTerms(elevation), offsets)
    folded = FactoryTerms(elevation + offsets[:, 2], azimuth_offset_rad=offsets[:, 1], range_offset_m=offsets[:, 0],
                          height_offset_m=offsets[:, 3])
    np.testing.assert_allclose(to_xyz(range_m, azimuth, folded, np.zeros((n, 4))), calibrated, atol=1e-12)
