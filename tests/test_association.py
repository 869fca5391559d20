"""Association: features against known shapes, neighbouring fibres, gated nearest neighbours."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from graphcal.calibration.association import (
    Features,
    PairCloud,
    PairGates,
    Sight,
    associate,
    local_features,
    neighbour_fibres,
    stand_in_shifts,
    voxel_means,
)
from graphcal.recording.sensor import sensor_from_catalog


def test_features_of_a_plane_a_line_and_a_blob():
    rng = np.random.default_rng(0)
    plane = np.column_stack([rng.uniform(0, 5, 3000), rng.uniform(0, 5, 3000), np.zeros(3000)])
    tilt = np.radians(30.0)
    rotation = np.array([[1, 0, 0], [0, np.cos(tilt), -np.sin(tilt)], [0, np.sin(tilt), np.cos(tilt)]])
    features = local_features(plane @ rotation.T, radius_m=0.4)
    expected_normal = rotation @ [0, 0, 1]
    np.testing.assert_allclose(np.abs(features.normal @ expected_normal), 1.0, atol=1e-9)
    assert np.median(features.planarity) > 0.6  # 20-point patches
    assert np.median(features.out_of_plane_m) < 1e-9
    rough = plane + np.column_stack([np.zeros((3000, 2)), rng.normal(0, 0.002, 3000)])
    # 20 points, 3 of whose degrees of freedom the plane takes: s3^2 about (17/20) 2 mm^2 on average
    assert np.median(local_features(rough, radius_m=0.4).out_of_plane_m) == pytest.approx(0.002 * np.sqrt(17 / 20), rel=0.15)

    line = np.column_stack([np.linspace(0, 5, 2000), np.zeros(2000), np.zeros(2000)]) + rng.normal(0, 1e-4, (2000, 3))
    features = local_features(line, radius_m=0.2)
    assert np.median(features.planarity) < 0.1

    blob = rng.normal(0, 1, (3000, 3))
    features = local_features(blob, radius_m=1.0, max_nn=50)
    # no plane: neighbourhoods as thick as they are wide (the 50 nearest lie within about 0.6 m, a ball whose
    # points spread 0.6 / sqrt(5) = 0.27 m along every axis)
    assert np.median(features.planarity) < 0.25 and np.median(features.out_of_plane_m) > 0.15
    assert features.planarity.min() >= 0 and features.planarity.max() <= 1



def test_features_are_the_eigen_decomposition_of_each_neighbourhood():
    """Against independent math: each point's 20 nearest neighbours within 0.5 m (scipy), their covariance
    (NumPy, population) and its eigen-decomposition (LAPACK): the normal is the least axis, out_of_plane_m the
    square root of the least eigenvalue, planarity (s2 - s3) / s1. A cloud with planes, an edge, a rough patch
    and a few isolated points (fewer than three neighbours: planarity 0)."""
    rng = np.random.default_rng(4)
    ground = np.column_stack([rng.uniform(0, 4, 1500), rng.uniform(0, 4, 1500), rng.normal(0, 0.01, 1500)])
    wall = np.column_stack([rng.uniform(0, 4, 800), np.full(800, 4.0), rng.uniform(0, 3, 800)])
    lone = rng.uniform(20, 60, (5, 3))
    cloud = np.vstack([ground, wall, rng.normal([2, 2, 2], 0.3, (300, 3)), lone])
    features = local_features(cloud, radius_m=0.5, max_nn=20)
    distance, nearest = cKDTree(cloud).query(cloud, k=20, distance_upper_bound=0.5)
    for row in rng.choice(len(cloud) - len(lone), 300, replace=False):
        neighbourhood = cloud[nearest[row][np.isfinite(distance[row])]]
        if len(neighbourhood) < 3:
            assert features.planarity[row] == 0.0
            continue
        eigenvalues, eigenvectors = np.linalg.eigh(np.cov(neighbourhood.T, bias=True))
        s3, s2, s1 = np.sqrt(np.clip(eigenvalues, 0.0, None))
        assert abs(features.normal[row] @ eigenvectors[:, 0]) == pytest.approx(1.0, abs=1e-6 if s2 - s3 > 1e-3 else 1)
        assert features.out_of_plane_m[row] == pytest.approx(s3, abs=1e-6)
        assert features.planarity[row] == pytest.approx((s2 - s3) / s1, abs=1e-6)
    assert np.all(features.planarity[-len(lone):] == 0.0)

def test_static_rings_need_voxel_features():
    """A static head sees a wall at the same spots every revolution: a point's nearest
    neighbours are that spot seen again, a blob of range noise stretched along the beam whose
    smallest axis is not the wall's normal. Features from voxels span the rings and find it."""
    rng = np.random.default_rng(1)
    elevation = np.radians(np.arange(-6, 7) * 1.33)  # 13 rings, HDL-32E spacing
    azimuth = np.radians(np.arange(-20, 20, 0.16))
    phi, theta = (a.ravel() for a in np.meshgrid(elevation, azimuth))
    direction = np.column_stack([np.cos(phi) * np.cos(theta), np.cos(phi) * np.sin(theta), np.sin(phi)])
    range_m = 8.0 / direction[:, 0]  # the wall x = 8 m
    revolutions = [direction * (range_m + rng.normal(0, 0.02, len(range_m)))[:, None] for _ in range(15)]
    points = np.concatenate(revolutions)
    blobs = local_features(points, 0.5, 20)
    assert np.median(blobs.planarity) > 0.5  # they look planar, so they would be paired,
    assert np.mean(np.abs(blobs.normal[:, 0]) > np.cos(np.radians(10))) < 0.01  # with wrong normals
    features = local_features(points, 0.5, 20, voxel_m=0.1)
    assert np.mean(np.abs(features.normal[:, 0]) > np.cos(np.radians(10))) > 0.99
    assert np.median(features.planarity) > 0.5


def test_voxel_features_near_a_crease_take_the_plane_of_their_own_face():
    """A flat verge meeting a 20 deg slope (a ditch's edge), 100 returns per m2 with 1 cm of noise, as a noisy
    head's sparse drive sees it: the neighbourhood of a voxel mean within its reach of the crease straddles it,
    and its normal turns towards the other face. Against each face's true normal: the plane least_bent chooses
    turns less than half as far there, and as little as the nearest mean's on the faces away from the crease."""
    rng = np.random.default_rng(5)
    slope = np.radians(20.0)
    x, y = rng.uniform(-2, 2, 16_000), rng.uniform(-20, 20, 16_000)
    points = np.column_stack([x, y, np.where(x > 0, np.tan(slope) * x, 0.0)]) + rng.normal(0, 0.01, (16_000, 3))
    means = voxel_means(points, 0.1)
    nearest_mean = local_features(means, 0.5, 20).take(cKDTree(means).query(points)[1])
    least_bent = local_features(points, 0.5, 20, voxel_m=0.1)

    def turned_to_the_other_face_deg(features):
        normal = features.normal * np.sign(features.normal[:, 2])[:, None]
        tilt_deg = np.degrees(np.arctan2(-normal[:, 0], normal[:, 2]))  # about y; the slope's own is 20 deg
        return np.where(x > 0, np.degrees(slope) - tilt_deg, tilt_deg)

    near = (np.abs(x) > 0.1) & (np.abs(x) < 0.2) & (np.abs(y) < 19)
    away = (np.abs(x) > 0.5) & (np.abs(y) < 19)
    before, after = turned_to_the_other_face_deg(nearest_mean), turned_to_the_other_face_deg(least_bent)
    assert np.median(before[near]) > 2.0  # the straddling neighbourhoods' bend
    assert np.median(after[near]) < 0.5 * np.median(before[near])
    assert abs(np.median(after[away])) < 0.1 and abs(np.median(before[away])) < 0.1
    assert np.quantile(np.abs(after[away]), 0.9) < 1.1 * np.quantile(np.abs(before[away]), 0.9)


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
    pairs = associate(PairCloud(points, fibre, features), {0: [1, 2], 1: [0], 2: [1]}, PairGates(0.3))
    assert len(pairs) > 3000
    assert set(fibre[pairs.index_p]) <= {0, 1} and np.all(fibre[pairs.index_p] != fibre[pairs.index_m])
    distance = np.linalg.norm(points[pairs.index_p] - points[pairs.index_m], axis=1)
    assert distance.max() < 0.3
    np.testing.assert_allclose(np.abs(pairs.normal[:, 2]), 1.0, atol=1e-3)
    assert pairs.weight.min() >= 0.3
    capped = associate(PairCloud(points, fibre, features), {0: [1]}, PairGates(0.3, most=100),
                       rng=np.random.default_rng(0))
    assert len(capped) == 100


def test_a_capped_association_is_a_uniform_subset_of_the_uncapped_one():
    """The cap searches only as many candidates as it takes (in a random order): the pairs it keeps
    are pairs the uncapped association keeps, and every one of those is as likely to be drawn."""
    rng = np.random.default_rng(2)
    n = 3000
    a = np.column_stack([rng.uniform(0, 10, n), rng.uniform(0, 10, n), np.zeros(n)])
    tilted = np.column_stack([rng.uniform(0, 10, n), rng.uniform(0, 10, n), np.zeros(n)])
    tilted[:, 2] = 0.01 + np.where(tilted[:, 0] > 5, 2.0 * (tilted[:, 0] - 5), 0.0)  # half of it bends away
    points, fibre = np.vstack([a, tilted]), np.r_[np.zeros(n, int), np.ones(n, int)]
    features = local_features(points, radius_m=0.5)
    settings = dict(gate_m=0.3, min_planarity=0.3, min_normal_cos=np.cos(np.radians(10.0)), max_plane_distance_m=0.05)
    cloud = PairCloud(points, fibre, features)
    everything = associate(cloud, {0: [1]}, PairGates(**settings))
    kept = set(zip(everything.index_p.tolist(), everything.index_m.tolist()))
    assert 500 < len(kept) < 0.9 * n  # the bent half is refused
    drawn = np.zeros(n)
    for seed in range(200):
        capped = associate(cloud, {0: [1]}, PairGates(**settings, most=100), rng=np.random.default_rng(seed))
        assert len(capped) == 100 and set(zip(capped.index_p.tolist(), capped.index_m.tolist())) <= kept
        assert np.all(np.diff(capped.index_p) > 0)
        drawn[capped.index_p] += 1
    # each kept p drawn 200 * 100 / len(kept) times on average; binomial spread, no p favoured or left out
    expected = 200 * 100 / len(kept)
    counts = drawn[everything.index_p]
    assert abs(counts.mean() - expected) < 1e-9 and counts.std() < 2 * np.sqrt(expected)


def test_pairs_across_an_edge_are_refused():
    """Ground meets a wall: a ground point's nearest neighbour on the other fibre may lie on the
    wall, a pair that would pull the offsets even at the true calibration."""
    rng = np.random.default_rng(3)
    n = 3000
    ground = np.column_stack([rng.uniform(0, 4, n), rng.uniform(0, 4, n), np.zeros(n)])
    wall = np.column_stack([np.full(n, 4.0), rng.uniform(0, 4, n), rng.uniform(0, 4, n)])
    points = np.vstack([ground, wall])
    fibre = rng.integers(0, 2, 2 * n)
    features = local_features(points, radius_m=0.5)
    pairs = {(planarity, angle): associate(PairCloud(points, fibre, features), {0: [1], 1: [0]},
                                           PairGates(0.5, planarity, np.cos(np.radians(angle))))
             for planarity, angle in ((0.0, 90.0), (0.0, 20.0), (0.5, 20.0))}
    crossing = {key: np.sum((p.index_p < n) != (p.index_m < n)) for key, p in pairs.items()}
    assert crossing[0.0, 90.0] > 20 and crossing[0.0, 20.0] < crossing[0.0, 90.0] / 2 and crossing[0.5, 20.0] == 0
    strict = pairs[0.5, 20.0]
    distance = np.abs(np.einsum("ni,ni->n", strict.normal, points[strict.index_p] - points[strict.index_m]))
    assert len(strict) > 0.9 * 2 * n * 0.9 and distance.max() < 0.02  # the true geometry: nothing to pull


def test_pairs_between_parallel_faces_are_refused():
    """A cabin side 0.1 m inside the body side: both planar, same normal, but not one surface."""
    rng = np.random.default_rng(4)
    n = 3000
    body = np.column_stack([rng.uniform(0, 4, n), np.zeros(n), rng.uniform(0, 1.0, n)])
    cabin = np.column_stack([rng.uniform(0, 4, n), np.full(n, -0.1), rng.uniform(1.0, 1.5, n)])
    points = np.vstack([body, cabin])
    fibre = np.r_[np.zeros(n, int), np.ones(n, int)]  # the lower fibre sees the body, the upper the cabin
    features = local_features(points + np.c_[np.zeros((2 * n, 2)), (points[:, 2] > 1.0) * 5.0], radius_m=0.5)
    cloud = PairCloud(points, fibre, features)
    loose = associate(cloud, {0: [1], 1: [0]}, PairGates(0.5, min_planarity=0.0))
    strict = associate(cloud, {0: [1], 1: [0]}, PairGates(0.5, min_planarity=0.0, max_plane_distance_m=0.05))
    assert len(loose) > 100 and len(strict) == 0


def test_gate_zero_finds_nothing():
    points = np.random.default_rng(2).uniform(0, 1, (100, 3))
    features = local_features(points, radius_m=0.5)
    pairs = associate(PairCloud(points, np.r_[np.zeros(50, int), np.ones(50, int)], features), {0: [1]},
                      PairGates(1e-9, min_planarity=0.0))
    assert len(pairs) == 0 and pairs.normal.shape == (0, 3)


@pytest.mark.parametrize("n_steps", [1, 3])
def test_neighbourhood_is_symmetric(n_steps):
    neighbours = neighbour_fibres(sensor_from_catalog("HDL-64E").elevation_deg, n_steps)
    for i, js in neighbours.items():
        for j in js:
            assert i in neighbours[j]


def test_line_of_sight_choice_is_not_biased_by_range_noise():
    """Two rings on flat ground (HDL-32E azimuth step), 1 cm range noise, many independent sweeps.
    The nearest return of the outer ring to p is the one whose noise pulled it in towards p, which
    also lifted it (its line of sight slopes down): the residual n.(p - m) is biased. Chosen by
    stand-ins that leave each return's own range out, then by the line of sight passing nearest p,
    m does not depend on its noise: no bias (independent math: the true residual is 0 on a plane)."""
    rng = np.random.default_rng(3)
    height_m, noise_m, sweeps = 2.0, 0.01, 200
    step = np.radians(0.16)
    azimuth = np.arange(-0.5, 0.5, step)
    per_ring = len(azimuth)
    elevation = np.radians(np.repeat([-10.0, -9.8], per_ring * sweeps))  # rings 0.23 m apart
    azimuth = np.concatenate([np.tile(azimuth, sweeps) + np.repeat(rng.uniform(0, step, sweeps), per_ring)
                              for _ in range(2)])  # each fibre's returns in firing order, sweep by sweep
    origin = np.zeros((len(azimuth), 3))
    origin[:, 1] = np.tile(np.repeat(np.arange(sweeps) * 100.0, per_ring), 2)  # sweeps 100 m apart
    rays = np.column_stack([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth),
                            np.sin(elevation)])
    range_m = -height_m / rays[:, 2] + rng.normal(0, noise_m, len(rays))
    points = origin + rays * range_m[:, None]
    fibre = np.repeat([0, 1], per_ring * sweeps)
    flat = np.ones(len(points))
    features = Features(np.tile([0.0, 0.0, 1.0], (len(points), 1)), flat, 0 * flat)

    def mean_and_error(pairs):
        r = points[pairs.index_p, 2] - points[pairs.index_m, 2]
        return r.mean(), r.std() / np.sqrt(len(r))

    nearest = associate(PairCloud(points, fibre, features), {0: [1]}, PairGates(0.3))
    sight = Sight(rays, stand_in_shifts(fibre, range_m, azimuth))
    line_of_sight = associate(PairCloud(points, fibre, features, sight), {0: [1]}, PairGates(0.3))
    assert len(line_of_sight) > 0.9 * len(nearest) > 0.9 * per_ring * sweeps * 0.9
    biased, error = mean_and_error(nearest)
    assert biased < -10 * error  # m lifted
    unbiased, error = mean_and_error(line_of_sight)
    assert abs(unbiased) < 3 * error


@pytest.mark.parametrize("behind_m, chosen", [(0.9, "beside"), (0.28, "behind")])
def test_the_line_of_sight_choice_reaches_only_as_far_as_the_fine_gate(behind_m, chosen):
    """p and two returns of the next fibre within a coarse gate of 1 m: one 0.25 m beside p, seen from the head at the
    origin (its line of sight misses p by 0.25 m), one behind_m further along a line of sight through p (a surface
    behind p, seen past it from elsewhere). Beyond LINE_REACH_M the one behind is no candidate, whatever its line:
    the one beside is m; within the reach the line of sight decides."""
    p = np.array([5.0, 0.0, -2.0])
    through_p = np.array([0.6, 0.0, -0.8])
    beside, behind = p + [0.0, 0.25, 0.0], p + behind_m * through_p
    rays = np.array([p / np.linalg.norm(p), beside / np.linalg.norm(beside), through_p])
    points = np.array([p, beside, behind])
    features = Features(np.tile([0.0, 0.0, 1.0], (3, 1)), np.ones(3), np.zeros(3))
    cloud = PairCloud(points, np.array([0, 1, 1]), features, Sight(rays, np.zeros(3)))
    pairs = associate(cloud, {0: [1]}, PairGates(1.0), candidates=np.array([0]))
    assert list(pairs.index_p) == [0] and list(pairs.index_m) == [1 if chosen == "beside" else 2]


@pytest.mark.parametrize("surface", ["ground", "wall"])
def test_stand_ins_lie_on_a_tilted_heads_plane_at_a_subsamples_spacing(surface):
    """A head pitched 12 deg, one revolution of a fibre with a tenth of its firings kept at random (a subsample's
    spacing, about 1.6 deg): a downward fibre (-25 deg) over flat ground 1.9 m below, or an upward one (+5 deg)
    before a wall 6 m ahead. The range (the plane's distance over the cosine between its normal and the ray,
    independent math) curves with the azimuth. Without noise each return's stand-in must be its own range: a line
    through two neighbours on each side misses it (the ground ring by about a millimetre, with one sign along the
    ring; the wall by 7 mm), a parabola through them misses the wall by a tenth of a millimetre."""
    rng = np.random.default_rng(5)
    pitch = np.radians(12.0)
    elevation = np.radians(-25.0 if surface == "ground" else 5.0)
    azimuth = np.sort(rng.choice(np.arange(0, 2 * np.pi, np.radians(0.16)), 225, replace=False))
    rays = np.column_stack([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth),
                            np.full(len(azimuth), np.sin(elevation))])
    if surface == "ground":
        facing, distance_m = np.sin(pitch) * rays[:, 0] - np.cos(pitch) * rays[:, 2], 1.9  # the ray's depression
    else:
        facing, distance_m = np.cos(pitch) * rays[:, 0] + np.sin(pitch) * rays[:, 2], 6.0  # the ray's forward x
    seen = facing > 0.5
    azimuth, rays, range_m = azimuth[seen], rays[seen], distance_m / facing[seen]
    shift_m = stand_in_shifts(np.zeros(len(rays), int), range_m, azimuth)
    found = shift_m[2:-2] != 0
    assert np.mean(found) > 0.8  # the stand-ins found (the wall's segment has two ends)

    def missed_by(degree):  # [m], of a polynomial through two neighbours on each side, where a stand-in was found
        return np.abs([np.polyval(np.polyfit(azimuth[i - 2:i + 3][[0, 1, 3, 4]] - azimuth[i],
                                             range_m[i - 2:i + 3][[0, 1, 3, 4]], degree), 0.0) - range_m[i]
                       for i in range(2, len(azimuth) - 2)])[found]

    assert np.median(missed_by(1)) > (5e-4 if surface == "ground" else 5e-3)
    if surface == "wall":
        assert np.median(missed_by(2)) > 1e-4
    assert np.max(np.abs(shift_m[2:-2][found])) < 1e-6
