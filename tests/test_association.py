"""Association: features against known shapes, neighbouring fibres, gated nearest neighbours."""

import numpy as np
import pytest

from graphcal.association import associate, local_features, neighbour_fibres
from graphcal.sensor import sensor_from_catalog


def test_features_of_a_plane_a_line_and_a_blob():
    rng = np.random.default_rng(0)
    plane = np.column_stack([rng.uniform(0, 5, 3000), rng.uniform(0, 5, 3000), np.zeros(3000)])
    tilt = np.radians(30.0)
    rotation = np.array([[1, 0, 0], [0, np.cos(tilt), -np.sin(tilt)], [0, np.sin(tilt), np.cos(tilt)]])
    features = local_features(plane @ rotation.T, radius_m=0.4)
    expected_normal = rotation @ [0, 0, 1]
    np.testing.assert_allclose(np.abs(features.normal @ expected_normal), 1.0, atol=1e-9)
    assert np.median(features.planarity) > 0.6 and np.median(features.scattering) < 1e-6  # 20-point patches

    line = np.column_stack([np.linspace(0, 5, 2000), np.zeros(2000), np.zeros(2000)]) + rng.normal(0, 1e-4, (2000, 3))
    features = local_features(line, radius_m=0.2)
    assert np.median(features.linearity) > 0.95 and np.median(features.planarity) < 0.1

    blob = rng.normal(0, 1, (3000, 3))
    features = local_features(blob, radius_m=1.0, max_nn=50)
    assert np.median(features.scattering) > 0.3
    for values in (features.linearity, features.planarity, features.scattering):
        assert values.min() >= 0 and values.max() <= 1


def test_neighbour_fibres_follow_elevation_order():
    sensor = sensor_from_catalog("HDL-32E")
    neighbours = neighbour_fibres(sensor.elevation_deg, 1)
    assert sorted(neighbours[15]) == [13, 17]  # -1.33 and +1.33 deg around the 0 deg reference
    assert neighbours[0] == [2]  # the lowest beam (-30.67) has one neighbour, -29.33
    two = neighbour_fibres(sensor.elevation_deg, 2)
    assert all(len(v) <= 4 for v in two.values()) and sorted(two[15]) == [11, 13, 17, 19]


def test_associate_pairs_points_of_neighbouring_fibres_on_a_plane():
    rng = np.random.default_rng(1)
    n = 2000
    a = np.column_stack([rng.uniform(0, 10, n), rng.uniform(0, 10, n), np.zeros(n)])
    b = a + np.column_stack([rng.normal(0, 0.02, n), rng.normal(0, 0.02, n), np.full(n, 0.01)])
    far = a[:200] + [0, 0, 5.0]  # a third fibre far above: outside the gate
    points = np.vstack([a, b, far])
    fibre = np.r_[np.zeros(n, int), np.ones(n, int), np.full(200, 2)]
    features = local_features(points, radius_m=0.5)
    pairs = associate(points, fibre, features, {0: [1, 2], 1: [0], 2: [1]}, gate_m=0.3)
    assert len(pairs) > 3000
    assert set(fibre[pairs.index_p]) <= {0, 1} and np.all(fibre[pairs.index_p] != fibre[pairs.index_m])
    distance = np.linalg.norm(points[pairs.index_p] - points[pairs.index_m], axis=1)
    assert distance.max() < 0.3
    np.testing.assert_allclose(np.abs(pairs.normal[:, 2]), 1.0, atol=1e-3)
    assert pairs.weight.min() >= 0.3
    capped = associate(points, fibre, features, {0: [1]}, gate_m=0.3, max_pairs_per_fibre_pair=100,
                       rng=np.random.default_rng(0))
    assert len(capped) == 100


def test_gate_zero_finds_nothing():
    points = np.random.default_rng(2).uniform(0, 1, (100, 3))
    features = local_features(points, radius_m=0.5)
    pairs = associate(points, np.r_[np.zeros(50, int), np.ones(50, int)], features, {0: [1]}, gate_m=1e-9,
                      min_planarity=0.0)
    assert len(pairs) == 0 and pairs.normal.shape == (0, 3)


@pytest.mark.parametrize("n_steps", [1, 3])
def test_neighbourhood_is_symmetric(n_steps):
    neighbours = neighbour_fibres(sensor_from_catalog("HDL-64E").elevation_deg, n_steps)
    for i, js in neighbours.items():
        for j in js:
            assert i in neighbours[j]
