"""Deskew (seed 002) against the truth of simulated drives and independent closed forms."""

import dataclasses

import laspy
import numpy as np
import open3d as o3d
import pytest
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

import graphcal
import graphcal.recording.points
from graphcal.cli.main import app
from graphcal.clouds.formats import pose_to_3dtk, read_3dtk_pose
from graphcal.deskewing.metrics import DeskewMetrics, icp_errors, occupied_cells, truth_distance
from graphcal.deskewing.deskew import iter_scans, relative_lidar_poses
from graphcal.common.errors import ConfigError, RecordingError
from graphcal.recording.points import PointTable
from graphcal.recording.directory import Recording
from graphcal.deskewing.scan_files import POSE_COLUMNS
from graphcal.simulation.odometry import simulate_odometry
from graphcal.simulation.scenario import OdometrySpec
from graphcal.simulation.script import load_scenario_builder
from graphcal.simulation.simulator import simulate
from graphcal.common.tables import read_csv_columns

SIZE = 0.05


def simulated(name, **changes):
    scenario = load_scenario_builder(name)(size=SIZE, **changes)
    return scenario, simulate(scenario, quiet=True)


@pytest.fixture(scope="module")
def linear():
    return simulated("deskew_linear")


@pytest.fixture(scope="module")
def rotation():
    return simulated("deskew_rotation")


def whole_revolutions(scans):
    return scans[1:-1]  # the first and last revolutions of a recording are partial


def lag_s(scans):
    """Time from each return to its revolution's end [s]."""
    return np.concatenate([scan.time_end_s - scan.time_s for scan in scans])


def test_raw_scan_at_50_km_h_is_off_by_the_distance_driven():
    """Seed 002, 2.1: 1.38 m between the start and the end of a scan at 50 km/h, HDL-64E, 10 Hz."""
    speed = 50 / 3.6
    _, recording = simulated("deskew_linear", speed_m_s=speed)
    raw = whole_revolutions(graphcal.deskew(recording, "none", quiet=True))
    error = truth_distance(raw, recording)
    np.testing.assert_allclose(error, speed * lag_s(raw), atol=1e-4)  # a translation of v * lag
    assert error.max() == pytest.approx(1.38, abs=0.012)


def test_raw_scan_turning_at_25_deg_s_is_off_by_the_arc(rotation):
    """Seed 002, 2.1: 2.19 m at 50 m range when turning at 25 deg/s. The vehicle circles the
    scene's centre, so a raw return is the true one turned by omega * lag about that centre."""
    scenario, recording = rotation
    raw = whole_revolutions(graphcal.deskew(recording, "none", quiet=True))
    error = truth_distance(raw, recording)
    true_local = np.concatenate([recording.truth.world_points()[s.first_row:s.first_row + len(s.xyz_m)]
                                 for s in raw]) - np.asarray(scenario.origin_m)
    from_centre = np.hypot(true_local[:, 0], true_local[:, 1])
    chord = 2 * from_centre * np.sin(np.radians(25.0) * lag_s(raw) / 2)
    np.testing.assert_allclose(error, chord, atol=2e-4)
    at_50_m = (np.abs(from_centre - 50.0) < 0.5) & (lag_s(raw) > 0.098)
    assert at_50_m.sum() > 20
    assert error[at_50_m].max() == pytest.approx(2.19, abs=0.03)


@pytest.mark.parametrize("source,gyro", [("ins", True), ("odometry", True), ("odometry", False)])
@pytest.mark.parametrize("name", ["linear", "rotation"])
def test_deskew_brings_the_returns_20_times_closer_to_the_truth(name, source, gyro, request):
    _, recording = request.getfixturevalue(name)
    raw = truth_distance(graphcal.deskew(recording, "none", quiet=True), recording)
    deskewed = truth_distance(graphcal.deskew(recording, source, use_gyro=gyro, quiet=True), recording)
    assert raw.mean() > 0.4  # half a metre on average, 1 m (linear) to 3 m (rotation) at most
    assert deskewed.mean() * 20 < raw.mean()
    assert deskewed.max() < 1e-3  # the nearest-knot bound (v + omega r) 10 us


def test_deskew_equals_the_exact_per_return_motion(rotation):
    _, recording = rotation
    scans = graphcal.deskew(recording, "ins", quiet=True)
    raw = graphcal.deskew(recording, "none", quiet=True)
    time = np.concatenate([s.time_s for s in scans])
    end = np.concatenate([np.full(len(s.time_s), s.time_end_s) for s in scans])
    R, t = relative_lidar_poses(recording.world.poses, recording.extrinsic, time, end)  # SLERP at every return
    exact = np.einsum("nij,nj->ni", R, np.concatenate([s.xyz_m for s in raw])) + t
    np.testing.assert_allclose(np.concatenate([s.xyz_m for s in scans]), exact, atol=5e-4)


def test_odometry_noise_degrades_the_deskew_in_proportion(rotation):
    scenario, recording = rotation
    means = []
    for noise in (0.0, 0.002, 0.004, 0.008):
        spec = OdometrySpec(wheel_noise_rad=noise)
        odometry = simulate_odometry(scenario.drive, spec, scenario.start_time_s, scenario.duration_s,
                                     np.random.default_rng(7))
        noisy = dataclasses.replace(recording, odometry=odometry)
        means.append(truth_distance(graphcal.deskew(noisy, "odometry", quiet=True), noisy).mean())
    assert means[0] < 1e-4 < means[1] < means[2] < means[3]
    assert means[3] / means[1] == pytest.approx(4.0, rel=0.25)  # the same draws scaled: error ~ noise


def test_seed_metrics_raw_against_deskewed(linear, rotation):
    for _, recording in (linear, rotation):
        raw = DeskewMetrics.of(graphcal.deskew(recording, "none", quiet=True), recording)
        deskewed = DeskewMetrics.of(graphcal.deskew(recording, "odometry", quiet=True), recording)
        assert deskewed.occupied_cells < 0.99 * raw.occupied_cells  # Table 2: fewer cells
        # fig. 8's finding: successive scans share their distortion, so ICP matches raw scans as
        # well as deskewed ones (here the residual is mostly the spacing of the thinned returns)
        assert deskewed.icp_rmse_m == pytest.approx(raw.icp_rmse_m, rel=0.05)
        assert deskewed.truth.mean * 20 < raw.truth.mean


def test_metric_functions_on_known_clouds():
    grid = np.stack(np.meshgrid(np.arange(3), np.arange(4), np.arange(5), indexing="ij"), -1).reshape(-1, 3)
    cloud = 0.1 * grid + 0.05
    assert occupied_cells(np.concatenate([cloud, cloud + 0.01])) == 60
    points = np.random.default_rng(0).uniform(-20, 20, (3000, 3))
    turned = Rotation.from_euler("z", 3, degrees=True)
    scans = [_FakeScan(points, Rotation.identity(), np.zeros(3)),
             _FakeScan(turned.inv().apply(points - [1.0, 0, 0]), turned, np.array([1.0, 0, 0]))]
    pair, = icp_errors(scans, voxel_m=0.01)
    assert pair.rmse_m < 1e-9 and pair.fitness == 1.0


@dataclasses.dataclass
class _FakeScan:
    xyz_m: np.ndarray
    rotation_world_lidar: Rotation
    position_world_lidar_m: np.ndarray


def test_revolutions_from_the_azimuth_and_across_batches(linear, monkeypatch):
    _, recording = linear
    reference = graphcal.deskew(recording, "ins", quiet=True)
    columns = recording.points.read()
    del columns["scan"]
    no_counter = dataclasses.replace(recording, points=PointTable.from_arrays(**columns))
    monkeypatch.setattr(graphcal.recording.points, "BATCH_ROWS", 5000)
    for variant in (recording, no_counter):
        scans = list(iter_scans(variant, "ins", quiet=True))
        assert [s.first_row for s in scans] == [s.first_row for s in reference]
        np.testing.assert_array_equal(np.concatenate([s.xyz_m for s in scans]),
                                      np.concatenate([s.xyz_m for s in reference]))


def test_bad_sources_and_uncovered_odometry(linear):
    _, recording = linear
    with pytest.raises(ConfigError, match="expected one of ins, odometry, none"):
        graphcal.deskew(recording, "gps")
    with pytest.raises(RecordingError, match="odometry.csv: file not found"):
        graphcal.deskew(dataclasses.replace(recording, odometry=None), "odometry")
    late = dataclasses.replace(recording.odometry, time=recording.odometry.time + 1.0)
    with pytest.raises(RecordingError, match="odometry.csv, field 'time'.*covering the returns"):
        graphcal.deskew(dataclasses.replace(recording, odometry=late), "odometry")


def euler_to_matrix_3dtk(angles_deg):
    """3DTK's EulerToMatrix4 (include/slam6d/globals.icc), column-major alignxf, as a 3x3."""
    sx, sy, sz = np.sin(np.radians(angles_deg))
    cx, cy, cz = np.cos(np.radians(angles_deg))
    alignxf = [cy * cz, sx * sy * cz + cx * sz, -cx * sy * cz + sx * sz, -cy * sz, -sx * sy * sz + cx * cz,
               cx * sy * sz + sx * cz, sy, -sx * cy, cx * cy]
    return np.array(alignxf).reshape(3, 3).T


def test_3dtk_pose_convention():
    to_3dtk = np.array([[0, -1, 0], [0, 0, 1], [1, 0, 0]])  # x right, y up, z forward, as 3DTK's readers map
    for rotation in Rotation.random(50, random_state=3):
        position_cm, angles = pose_to_3dtk(rotation.as_matrix(), np.array([1.0, 2.0, 3.0]))
        np.testing.assert_allclose(euler_to_matrix_3dtk(angles), to_3dtk @ rotation.as_matrix() @ to_3dtk.T,
                                   atol=1e-12)
        np.testing.assert_allclose(position_cm, [-200.0, 300.0, 100.0])
    _, angles = pose_to_3dtk(Rotation.from_euler("z", 30, degrees=True).as_matrix(), np.zeros(3))
    np.testing.assert_allclose(angles, [0.0, -30.0, 0.0], atol=1e-12)  # a yaw is one 3DTK angle


@pytest.mark.parametrize("cloud_format", ["ply", "las", "uos"])
def test_cli_writes_scans_and_poses_that_read_back(rotation, tmp_path, cloud_format):
    _, recording = rotation
    path = recording.save(tmp_path / "rec")
    out = tmp_path / "scans"
    result = CliRunner().invoke(app, ["deskew", str(path), "--source", "odometry", "--format", cloud_format,
                                      "--out", str(out), "-q"])
    assert result.exit_code == 0, result.output
    scans = graphcal.deskew(Recording.load(path), "odometry", quiet=True)
    _, poses = read_csv_columns(out / "poses.csv", (POSE_COLUMNS,))
    assert len(poses) == len(scans) and poses[:, -1].sum() == len(recording.points)
    origin = np.floor(scans[0].position_world_lidar_m)
    for k in (0, len(scans) // 2):
        scan, name = scans[k], f"scan{k:03d}"
        np.testing.assert_allclose(poses[k, 3:6], scan.position_world_lidar_m, atol=1e-6)
        R, X = read_3dtk_pose(out / f"{name}.pose")
        np.testing.assert_allclose(R, scan.rotation_world_lidar.as_matrix(), atol=1e-8)
        np.testing.assert_allclose(X + origin, scan.position_world_lidar_m, atol=1e-7)
        if cloud_format == "ply":
            cloud = o3d.t.io.read_point_cloud(str(out / f"{name}.ply"))
            np.testing.assert_array_equal(cloud.point.positions.numpy(), scan.xyz_m)
            np.testing.assert_array_equal(cloud.point["time"].numpy().ravel(), scan.time_s)
            np.testing.assert_array_equal(cloud.point["fibre"].numpy().ravel(), scan.fibre)
        elif cloud_format == "las":
            las = laspy.read(out / f"{name}.las")
            np.testing.assert_allclose(np.column_stack([las.x, las.y, las.z]), scan.xyz_m, atol=5.1e-5)
            np.testing.assert_array_equal(las.gps_time, scan.time_s)
            np.testing.assert_array_equal(las.fibre, scan.fibre)
        else:
            xyz_3dtk = np.loadtxt(out / f"{name}.3d")
            np.testing.assert_allclose(xyz_3dtk / 100, scan.xyz_m @ np.array([[0, -1, 0], [0, 0, 1], [1, 0, 0]]).T,
                                       atol=6e-6)


def test_cli_bad_input_is_one_clear_line(tmp_path):
    runner = CliRunner()
    path = simulate(load_scenario_builder("deskew_rotation")(size=0.005, odometry=None), quiet=True).save(
        tmp_path / "no-odometry")
    result = runner.invoke(app, ["deskew", str(path), "--source", "odometry", "-q"])
    assert result.exit_code == 2 and result.output.count("\n") == 1
    assert f"{path / 'odometry.csv'}: file not found" in result.output
    for option, value in (("--source", "gps"), ("--format", "xyz")):
        result = runner.invoke(app, ["deskew", str(path), option, value])
        assert result.exit_code == 2 and value in result.output and "Traceback" not in result.output
    result = runner.invoke(app, ["deskew", str(tmp_path / "missing")])
    assert result.exit_code == 2 and "recording directory not found" in result.output
