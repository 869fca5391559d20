"""Features and pairs tile by tile of space (graphcal.calibration.tiles) against the whole cloud at once, and a
calibration whose tiles run on a Dask LocalCluster of two workers against the same calibration in one process."""

import numpy as np
import pytest

import graphcal
from graphcal.calibration.association import PairCloud, PairGates, associate, local_features, neighbour_fibres
from graphcal.calibration.config import CalibrationConfig
from graphcal.calibration.tiles import Tiling
from graphcal.common.cluster import OnCluster, local_workers
from graphcal.common.errors import ConfigError


def _street(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Returns of 8 'fibres' (bands 0.3 m wide, 4 along the ground, 4 up both facades) along a 120 m street,
    noisy by 2 mm, drawn independently of the tiling: the points [m] and each one's fibre."""
    parts, fibres = [], []
    for fibre in range(8):
        x = np.sort(rng.uniform(-60, 60, 12000))
        across = rng.uniform(-0.15, 0.15, len(x))
        if fibre < 4:  # the ground, bands centred at y = -1 .. -0.1 m
            xyz = np.column_stack([x, -1.0 + 0.3 * fibre + across, np.zeros_like(x)])
        else:  # the facades at y = +-8 m, bands centred 1 .. 1.9 m high
            side = np.where(rng.random(len(x)) < 0.5, -8.0, 8.0)
            xyz = np.column_stack([x, side, 1.0 + 0.3 * (fibre - 4) + across])
        parts.append(xyz + rng.normal(0, 0.002, xyz.shape))
        fibres.append(np.full(len(x), fibre))
    return np.concatenate(parts), np.concatenate(fibres)


def test_features_and_pairs_tile_by_tile_equal_those_of_the_whole_cloud():
    points, fibre = _street(np.random.default_rng(0))
    tiling = Tiling(20.0, 2.5)
    assert len(tiling.tiles(points)) >= 12
    whole = local_features(points, 0.5, 20)
    settings = CalibrationConfig().features.model_copy(update={"radius_m": 0.5, "neighbours": 20, "voxel_m": 0.0})
    tiled = tiling.features(points, settings)
    np.testing.assert_allclose(tiled.planarity, whole.planarity, atol=1e-9)
    np.testing.assert_allclose(np.abs(np.einsum("ni,ni->n", tiled.normal, whole.normal)), 1.0, atol=1e-9)
    neighbours = neighbour_fibres(np.arange(8.0), 2)
    gates = PairGates(1.0, 0.3, 0.0, np.inf, None)  # uncapped: no random draw to differ
    candidates = np.arange(0, len(points), 7)
    at_once = associate(PairCloud(points, fibre, whole), neighbours, gates, np.random.default_rng(0), candidates)
    by_tile = tiling.associate(PairCloud(points, fibre, tiled), neighbours, gates, 0, candidates)
    assert len(at_once) > 10_000
    assert set(zip(by_tile.index_p.tolist(), by_tile.index_m.tolist())) == set(
        zip(at_once.index_p.tolist(), at_once.index_m.tolist()))


def test_features_from_voxels_tile_by_tile_equal_those_of_the_whole_cloud():
    """A tile's halo averages the voxels of its core on the whole cloud's grid, as the whole cloud does: features
    from voxels (a noisy head's, a static sensor's) do not depend on the tiling."""
    points, _ = _street(np.random.default_rng(2))
    points = points + np.random.default_rng(3).normal(0, 0.01, points.shape)  # a noisy head's 1 cm
    settings = CalibrationConfig().features.model_copy(update={"radius_m": 0.5, "neighbours": 20, "voxel_m": 0.1})
    whole = local_features(points, 0.5, 20, voxel_m=0.1)
    tiled = Tiling(20.0, 2.5).features(points, settings)
    np.testing.assert_allclose(tiled.planarity, whole.planarity, atol=1e-9)
    np.testing.assert_allclose(np.abs(np.einsum("ni,ni->n", tiled.normal, whole.normal)), 1.0, atol=1e-9)


def test_voxel_means_are_open3d_voxel_down_sample_s():
    """On the grid open3d's voxel_down_sample uses (a corner half a voxel below the points' least coordinates), the
    same means."""
    import open3d as o3d

    from graphcal.calibration.association import voxel_means

    points = np.random.default_rng(4).uniform(-3.5, 3.5, (20000, 3))
    means = voxel_means(points, 0.1)
    sampled = np.asarray(o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points)).voxel_down_sample(0.1).points)
    assert len(means) == len(sampled) > 10000
    np.testing.assert_allclose(means[np.lexsort(means.T)], sampled[np.lexsort(sampled.T)], atol=1e-12)


def test_a_tile_that_pairs_nothing_leaves_the_others_pairs_unchanged():
    """A lone return 500 m away makes a tile of its own with no pair; with lines of sight (Sight) as well."""
    from graphcal.calibration.association import Sight, stand_in_shifts

    points, fibre = _street(np.random.default_rng(1))
    lone_points, lone_fibre = np.vstack([points, [[500.0, 500.0, 0.0]]]), np.r_[fibre, 0]
    tiling = Tiling(20.0, 2.5)
    settings = CalibrationConfig().features.model_copy(update={"radius_m": 0.5, "neighbours": 20, "voxel_m": 0.0})
    gates, neighbours = PairGates(1.0, 0.3, 0.0, np.inf, None), neighbour_fibres(np.arange(8.0), 2)
    pairs = []
    for xyz, fibres in ((points, fibre), (lone_points, lone_fibre)):
        range_m = np.linalg.norm(xyz, axis=1)
        sight = Sight(xyz / range_m[:, None], stand_in_shifts(fibres, range_m, np.arctan2(-xyz[:, 1], xyz[:, 0])))
        cloud = PairCloud(xyz, fibres, tiling.features(xyz, settings), sight)
        pairs.append(tiling.associate(cloud, neighbours, gates, 0, np.arange(0, len(xyz), 7)))
    np.testing.assert_array_equal(pairs[1].index_p, pairs[0].index_p)
    np.testing.assert_array_equal(pairs[1].shift_m_m, pairs[0].shift_m_m)


def test_a_margin_wider_than_the_tile_is_refused():
    with pytest.raises(ValueError, match="margin"):
        Tiling(10.0, 12.0)


@pytest.mark.parametrize("address", ["local:0", "local:two"])
def test_a_bad_worker_count_names_the_option(address):
    with pytest.raises(ConfigError, match="--dask"):
        local_workers(address)


def test_two_dask_workers_give_the_calibration_of_one_process(tmp_path):
    from graphcal.simulation.script import load_scenario_builder

    recording = graphcal.simulate(load_scenario_builder("sim2_street")(size=0.05, seed=1), quiet=True)
    config = CalibrationConfig(mode="intrinsic", max_points=30_000, association={"tile_m": 20.0},
                               stopping={"max_outer_iterations": 2, "refuse_unconverged": False})
    here = graphcal.calibrate(recording, config, quiet=True)
    there = graphcal.calibrate(recording, config, quiet=True, dask="local:2")
    np.testing.assert_array_equal(there.calibration.estimate.offsets, here.calibration.estimate.offsets)
    assert there.energy_cm2 == here.energy_cm2


def _worker_of(job: int) -> tuple[int, str]:
    from dask.distributed import get_worker

    return job, get_worker().address


def test_a_cluster_returns_every_result_in_the_jobs_order_whichever_worker_ran_it():
    """More jobs than the workers hold at once, their stated costs in the opposite order to the jobs': each
    result in its job's place, and both workers given jobs."""
    from dask.distributed import Client, LocalCluster

    with (LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None) as cluster,
          Client(cluster) as client):
        results = OnCluster(client)(_worker_of, list(range(9)), costs=list(range(9)))
    assert [job for job, _ in results] == list(range(9))
    assert len({worker for _, worker in results}) == 2
