"""Simulator: raw returns agree with the truth it writes, effects do what they say, timing."""

import numpy as np
import pytest
from pydantic import ValidationError

import graphcal
from graphcal.common.errors import ConfigError
from graphcal.recording.geodesy import to_world
from graphcal.recording.georeference import georeference
from graphcal.simulation.drive import Drive, Spin, loop, spin, straight, turn
from graphcal.simulation.scenario import (
    ExtrinsicSpec,
    InsErrors,
    IntrinsicErrors,
    Scenario,
    draw_offsets,
)
from graphcal.simulation.scene import (
    Box,
    Facade,
    Ground,
    LATTICE_SHIFT,
    Markings,
    ParkedCar,
    Pole,
    RaycastScene,
    street,
)
from graphcal.simulation.simulator import simulate

SPEED = 10.0


def small(**changes) -> Scenario:
    base = dict(name="small", duration_s=0.8, size=0.1, scene=street(80, 16) + [Pole(xy=(10.0, 4.0))],
                drive=Drive(segments=straight(40), speed_knots=[(0, SPEED)]),
                intrinsic_errors=IntrinsicErrors(range_m=0.05, azimuth_deg=1.0, elevation_deg=1.0, h_z_m=0.05),
                extrinsic=ExtrinsicSpec(error_lever_arm_m=(0.02, -0.03, 0.05), error_boresight_deg=(0.3, -0.2, 0.5)))
    base.update(changes)
    return Scenario(**base)


def georeference_truth(recording, time=None, azimuth=None):
    """Raw returns georeferenced with the TRUE intrinsics, extrinsic and trajectory."""
    points, truth = recording.points.read(), recording.truth
    poses = to_world(truth.trajectory, recording.crs).poses
    return georeference(points["time"] if time is None else time, points["fibre"], points["range"],
                        points["azimuth"] if azimuth is None else azimuth, recording.sensor,
                        truth.extrinsic, poses, truth.intrinsics)


@pytest.fixture(scope="module")
def recording():
    return simulate(small(), quiet=True)


@pytest.mark.parametrize("trajectory_format", ["projected", "geodetic"])
def test_raw_returns_reproduce_the_true_cloud(trajectory_format):
    rec = simulate(small(trajectory_format=trajectory_format), quiet=True)
    error = np.linalg.norm(georeference_truth(rec) - rec.truth.world_points(), axis=1)
    assert len(error) > 10_000
    assert error.max() < 1e-4  # float32 range/azimuth storage and CSV rounding only


def test_nominal_model_is_wrong_where_the_truth_differs(recording):
    points = recording.points.read()
    nominal = georeference(points["time"], points["fibre"], points["range"], points["azimuth"], recording.sensor,
                           recording.extrinsic, recording.world.poses)
    error = np.linalg.norm(nominal - recording.truth.world_points(), axis=1)
    assert np.median(error) > 0.05


def test_truth_points_lie_on_the_scene():
    """Every true point is on an analytic surface: ground z = 0, facades |y| = 8 m, pole r = 0.15 m."""
    scenario = small(scene=street(80, 16, relief_spacing_m=0.0) + [Pole(xy=(10.0, 4.0), radius_m=0.15)])
    local = simulate(scenario, quiet=True).truth.world_points() - np.asarray(scenario.origin_m)
    ground = np.abs(local[:, 2]) < 1e-4
    facade = np.abs(np.abs(local[:, 1]) - 8.0) < 1e-4
    pole = ~ground & ~facade  # every other point must be on the pole
    assert ground.sum() > 1000 and facade.sum() > 1000 and pole.sum() > 50
    radius = np.hypot(local[pole, 0] - 10.0, local[pole, 1] - 4.0)
    assert radius.min() > 0.15 * np.cos(np.pi / 24) - 1e-4 and radius.max() < 0.15 + 1e-4  # 24-sided mesh


def test_markings_darken_every_other_cell_of_one_surface():
    """On the ground (one reflectivity) the intensity over cos(incidence) is 255 x reflectivity on light cells
    and (1 - contrast) of it on dark ones, which alternate along the drive's 1 m cells, each half of the area."""
    scenario = small(scene=street(80, 16, relief_spacing_m=0.0), markings=Markings(cell_m=1.0, contrast=0.6))
    recording = simulate(scenario, quiet=True)
    local = recording.truth.world_points() - np.asarray(scenario.origin_m)
    ground = np.abs(local[:, 2]) < 1e-4
    points = recording.points.read()
    poses = to_world(recording.truth.trajectory, recording.crs).poses
    position, rotation = poses.interpolate(points["time"][ground])
    lidar = position + rotation.apply(recording.truth.extrinsic.lever_arm_m) - np.asarray(scenario.origin_m)
    ray = local[ground] - lidar  # from the lidar's body-frame position: within 1 cm of the beam's origin
    cos_incidence = np.abs(ray[:, 2]) / np.linalg.norm(ray, axis=1)
    steep = cos_incidence > 0.3
    shade = points["intensity"][ground][steep] / (255 * 0.5 * cos_incidence[steep])
    cell = (np.floor(local[ground][steep, :2] + LATTICE_SHIFT).sum(axis=1) % 2).astype(bool)
    np.testing.assert_allclose(shade[~cell], 1.0, atol=0.05)
    np.testing.assert_allclose(shade[cell], 0.4, atol=0.05)
    assert 0.3 < cell.mean() < 0.7
    assert np.array_equal(Markings().factor(np.array([[0.2, 0.1, -1e-9], [0.2, 0.1, 1e-9]])), [1.0, 1.0])


def test_same_seed_same_recording_other_seed_other_noise():
    a, b = (simulate(small(range_noise_m=0.01, seed=3), quiet=True).points.read() for _ in range(2))
    c = simulate(small(range_noise_m=0.01, seed=4), quiet=True).points.read()
    for name in a:
        np.testing.assert_array_equal(a[name], b[name])
    assert not np.array_equal(a["range"], c["range"])


def test_range_noise_has_the_requested_sigma():
    clean = simulate(small(seed=5), quiet=True).points.read()
    noisy = simulate(small(seed=5, range_noise_m=0.01), quiet=True).points.read()
    np.testing.assert_array_equal(clean["azimuth"], noisy["azimuth"])
    assert np.std(noisy["range"] - clean["range"]) == pytest.approx(0.01, rel=0.03)


def test_firing_timing_and_encoder_azimuth():
    rec = simulate(small(size=1.0, duration_s=0.5, scene=[Box(center=(0, 0, 0), size_m=(60, 60, 60))],
                         intrinsic_errors=IntrinsicErrors()), quiet=True)
    points = rec.points.read()
    timing = rec.sensor.timing
    first = points["time"][:64]
    np.testing.assert_allclose(np.diff(first[:32]), timing.laser_spacing_s, atol=1e-9)  # 1.152 us apart
    np.testing.assert_allclose(first[32] - first[0], timing.cycle_s, atol=1e-9)  # 46.08 us cycles
    assert len(points["time"]) / (points["time"][-1] - points["time"][0]) == pytest.approx(32 / 46.08e-6, rel=1e-3)
    step = np.diff(points["azimuth"][::32].astype(np.float64))
    step = step[step > 0]
    np.testing.assert_allclose(step, 2 * np.pi * rec.sensor.rotation_hz * timing.cycle_s, atol=2e-6)
    assert set(np.unique(points["scan"])) == {0, 1, 2}  # 0.3 s of recording inside 0.5 s


def test_frozen_sweep_without_intra_sweep_motion():
    """Switching the effect off casts every revolution from its start pose."""
    rec = simulate(small(effects={"intra_sweep_motion": False}), quiet=True)
    points = rec.points.read()
    t_rev = points["time"] - (points["azimuth"] / (2 * np.pi * rec.sensor.rotation_hz))
    per_return = np.linalg.norm(georeference_truth(rec) - rec.truth.world_points(), axis=1)
    frozen = np.linalg.norm(georeference_truth(rec, time=t_rev) - rec.truth.world_points(), axis=1)
    assert frozen.max() < 1e-3
    assert per_return.max() == pytest.approx(SPEED / rec.sensor.rotation_hz, rel=0.05)  # 1 m over a sweep


def test_revolution_stamping_writes_the_revolution_time():
    rec = simulate(small(effects={"intra_sweep_motion": {"stamp": "revolution"}}), quiet=True)
    points = rec.points.read()
    assert len(np.unique(points["time"])) == len(np.unique(points["scan"]))
    own_time = points["time"] + points["azimuth"] / (2 * np.pi * rec.sensor.rotation_hz)
    error = np.linalg.norm(georeference_truth(rec, time=own_time) - rec.truth.world_points(), axis=1)
    assert error.max() < 1e-3


def test_time_offset_shifts_the_stamps():
    offset = 0.02
    rec = simulate(small(effects={"time_offset": {"offset_s": offset}}), quiet=True)
    time = rec.points.read(["time"])["time"]
    shifted = np.linalg.norm(georeference_truth(rec, time=time - offset) - rec.truth.world_points(), axis=1)
    assert shifted.max() < 1e-4
    assert rec.truth.effects["time_offset"]["magnitude"] == offset


def test_switched_off_effect_changes_nothing():
    plain = simulate(small(seed=2), quiet=True).points.read()
    off = simulate(small(seed=2, effects={"time_offset": False, "range_scale": False}), quiet=True).points.read()
    for name in plain:
        np.testing.assert_array_equal(plain[name], off[name])


def test_range_scale_scales_every_range():
    plain = simulate(small(seed=1), quiet=True).points.read()
    scaled = simulate(small(seed=1, effects={"range_scale": {"scale": 1e-3}}),
                      quiet=True).points.read()
    np.testing.assert_allclose(scaled["range"], plain["range"] * 1.001, rtol=2e-7)


def test_incidence_bias_grows_with_obliquity():
    plain = simulate(small(seed=1), quiet=True).points.read()
    biased = simulate(small(seed=1, effects={"incidence_range_bias": {"bias_m": 0.1}}),
                      quiet=True).points.read()
    delta = biased["range"].astype(np.float64) - plain["range"]
    assert delta.min() > -1e-5 and delta.max() < 0.1 and delta.max() > 0.05


def test_azimuth_eccentricity_bends_the_beam_not_the_encoder():
    spec = {"amplitude_deg": 0.2, "phase_deg": 30.0}
    rec = simulate(small(effects={"azimuth_eccentricity": spec}), quiet=True)
    azimuth = rec.points.read(["azimuth"])["azimuth"].astype(np.float64)
    bent = azimuth + np.radians(0.2) * np.sin(azimuth + np.radians(30.0))
    assert np.linalg.norm(georeference_truth(rec, azimuth=bent) - rec.truth.world_points(), axis=1).max() < 1e-4
    assert np.linalg.norm(georeference_truth(rec) - rec.truth.world_points(), axis=1).max() > 0.01


def test_heading_drift_and_ins_errors():
    ins = InsErrors(rate_hz=50.0, piecewise_error_m=0.13, piecewise_interval_s=0.2)
    rec = simulate(small(duration_s=3.0, drive=Drive(segments=straight(50), speed_knots=[(0, SPEED)]), ins=ins,
                         effects={"heading_drift": {"rate_deg_s": 0.01}, "heading_bias": {"bias_deg": 0.05}}),
                   quiet=True)
    recorded, true = rec.world.poses, to_world(rec.truth.trajectory, rec.crs).poses
    true_at = true.resample(recorded.time)
    yaw_error = recorded.rpy_deg[:, 2] - true_at.rpy_deg[:, 2]
    np.testing.assert_allclose(yaw_error, 0.05 + 0.01 * (recorded.time - recorded.time[0]), atol=1e-6)
    error = recorded.position_m - true_at.position_m
    rms = np.sqrt(np.mean(np.sum(error ** 2, axis=1)))
    assert 0.05 < rms < 0.25  # 16 knots of a 13 cm RMS error
    second_difference = np.diff(error[:10], 2, axis=0)  # inside the first 0.2 s interval
    np.testing.assert_allclose(second_difference, 0.0, atol=1e-9)


def test_intrinsic_errors_have_the_table_4_1_rms():
    errors = IntrinsicErrors(range_m=0.10, azimuth_deg=3.0, elevation_deg=3.0, h_z_m=0.10, rms=(0.10, 2.5, 3.0, 0.10))
    offsets = draw_offsets(errors, 32, 15, np.random.default_rng(0))
    in_units = offsets * [1, 180 / np.pi, 180 / np.pi, 1]
    others = np.delete(in_units, 15, axis=0)
    np.testing.assert_allclose(np.sqrt(np.mean(others ** 2, axis=0)), [0.10, 2.5, 3.0, 0.10], rtol=1e-12)
    assert np.all(np.abs(others) <= [0.1 + 1e-12, 3 + 1e-12, 3 + 1e-12, 0.1 + 1e-12])
    np.testing.assert_array_equal(offsets[15], 0.0)
    with pytest.raises(ValidationError, match="rms"):
        IntrinsicErrors(azimuth_deg=1.0, rms=(0, 2.0, 0, 0))


def test_moving_object_moves_in_the_truth():
    car = Box(center=(15.0, 4.0, 1.0), size_m=(4.0, 2.0, 2.0), velocity_m_s=(5.0, 0.0, 0.0), reflectivity=0.9)
    rec = simulate(small(scene=[Ground(size_m=(200, 200)), car], intrinsic_errors=IntrinsicErrors()), quiet=True)
    points, world = rec.points.read(), rec.truth.world_points() - np.asarray(small().origin_m)
    on_car = world[:, 2] > 0.5
    elapsed = points["time"][on_car] - small().start_time_s
    # front face x = 13 + 5 t (seen from behind... the vehicle starts at x=0 heading +x)
    assert on_car.sum() > 100
    np.testing.assert_allclose(world[on_car, 0].min() - (13.0 + 5.0 * elapsed[np.argmin(world[on_car, 0])]), 0.0,
                               atol=0.06)
    slope = np.polyfit(elapsed, world[on_car, 0], 1)[0]
    assert slope == pytest.approx(5.0, abs=1.0)


def test_drive_geometry():
    drive = Drive(segments=straight(10) + turn(20.0, 90.0) + straight(5), speed_knots=[(0, 2.0), (2, 6.0)],
                  start_xy=(1.0, 2.0), start_yaw_deg=0.0)
    t = np.linspace(0, 6, 6001)
    s = drive.distance(t)
    numeric = np.concatenate([[0], np.cumsum(np.diff(t) * np.interp((t[1:] + t[:-1]) / 2, [0, 2], [2, 6]))])
    np.testing.assert_allclose(s, numeric, atol=1e-6)
    xyz, yaw = drive.pose_at_distance(np.linspace(10, 10 + 20 * np.pi / 2, 50))
    np.testing.assert_allclose(np.hypot(xyz[:, 0] - 11.0, xyz[:, 1] - 22.0), 20.0, atol=1e-9)  # on the circle
    np.testing.assert_allclose(yaw[[0, -1]], [0.0, 90.0], atol=1e-9)
    xyz, yaw = drive.pose_at_distance(np.linspace(0, drive.length_m, 2001))
    heading = np.degrees(np.arctan2(np.diff(xyz[:, 1]), np.diff(xyz[:, 0])))
    np.testing.assert_allclose(heading, (yaw[1:] + yaw[:-1]) / 2, atol=1e-2)  # chords across junctions
    with pytest.raises(ConfigError, match="path is only"):
        drive.pose_at_distance(np.array([100.0]))
    closed = Drive(segments=loop(40, 20, 5), speed_knots=[(0, 1)])
    end, end_yaw = closed.pose_at_distance(np.array([closed.length_m]))
    np.testing.assert_allclose(end[0, :2], [0, 0], atol=1e-9)
    assert end_yaw[0] == pytest.approx(360.0)


def test_a_spin_turns_on_the_spot_while_the_speed_profile_waits():
    """A spin of 90 deg at 90 deg/s between two straights: the profile (0 to 5 m/s in 2 s, then 5 m/s) reaches it
    at 10 m after 3 s; the body stays there for 1 s while its heading turns at the yaw rate, then the profile resumes
    where it stopped along the new heading; the wheels turn opposite ways through the spin, by (track / 2) x 90 deg
    over the radius."""
    from graphcal.simulation.odometry import simulate_odometry
    from graphcal.simulation.scenario import OdometrySpec

    drive = Drive(segments=straight(10) + spin(90.0, 90.0) + straight(10), speed_knots=[(0, 0.0), (2, 5.0)])
    t = np.array([0.0, 2.0, 3.0, 3.5, 4.0, 5.0])
    xyz, yaw_deg = drive.pose_at(t)
    np.testing.assert_allclose(xyz[:, :2], [[0, 0], [5, 0], [10, 0], [10, 0], [10, 0], [10, 5]], atol=1e-9)
    np.testing.assert_allclose(yaw_deg, [0, 0, 0, 45, 90, 90], atol=1e-9)
    np.testing.assert_allclose(drive.distance(t), [0, 5, 10, 10, 10, 15], atol=1e-9)
    spec = OdometrySpec(rate_hz=100.0)
    odometry = simulate_odometry(drive, spec, 0.0, 5.0, np.random.default_rng(0))
    during = np.searchsorted(odometry.time, [3.0, 4.0])
    wheel_rad = spec.track_m / 2 * np.pi / 2 / spec.wheel_radius_m
    np.testing.assert_allclose(np.diff(odometry.wheel_left_rad[during]), -wheel_rad, atol=1e-9)
    np.testing.assert_allclose(np.diff(odometry.wheel_right_rad[during]), wheel_rad, atol=1e-9)
    for angle_deg, rate_deg_s in ((0.0, 10.0), (90.0, 0.0)):
        with pytest.raises(ValidationError):
            Spin(angle_deg=angle_deg, yaw_rate_deg_s=rate_deg_s)
    stopping = Drive(segments=straight(10) + spin(90.0, 45.0), speed_knots=[(0, 2.0), (2, 0.0)])  # covers 2 m
    with pytest.raises(ConfigError, match="short of its spin at 10.0 m"):
        stopping.pose_at(t)


def test_scene_builders_have_the_requested_extent():
    facade = Facade(start_xy=(0, 5), end_xy=(20, 5), height_m=10, relief_spacing_m=5, relief_depth_m=0.3)
    box = facade.mesh().get_axis_aligned_bounding_box()
    np.testing.assert_allclose(box.min_bound, [0.0, 4.5, 0.0], atol=1e-9)  # wall behind the line
    np.testing.assert_allclose(box.max_bound, [20.0, 5.3, 10.0], atol=1e-9)  # pilasters on the street side
    pole = Pole(xy=(3, 4), radius_m=0.2, height_m=5).mesh().get_axis_aligned_bounding_box()
    np.testing.assert_allclose(pole.max_bound, [3.2, 4.2, 5.0], atol=1e-3)
    car = ParkedCar(xy=(0, 0), yaw_deg=90).mesh().get_axis_aligned_bounding_box()
    np.testing.assert_allclose(car.max_bound - car.min_bound, [1.8, 4.5, 1.5], atol=1e-9)
    distance, index, normal = RaycastScene([Ground(z_m=-2.0)]).cast(np.zeros((1, 3)), np.array([[0, 0, -1.0]]))
    assert distance[0] == pytest.approx(2.0) and index[0] == 0 and abs(normal[0, 2]) == pytest.approx(1.0)


def test_scenario_validation_names_the_problem():
    with pytest.raises(ValidationError, match="unknown effect"):
        small(effects={"warp_drive": {}})
    with pytest.raises(ValidationError, match="offset_s"):
        small(effects={"time_offset": {}})
    with pytest.raises(ValidationError, match="unknown sensor"):
        small(sensor_model="HDL-16")
    with pytest.raises(ValidationError, match="size"):
        small(size=0.0)
    with pytest.raises(ValidationError, match="not projected"):
        small(crs="EPSG:4326")
    with pytest.raises(ValidationError, match="unknown CRS"):
        small(crs="EPSG:99999999")
    with pytest.raises(ConfigError, match="path is only"):
        simulate(small(duration_s=10.0), quiet=True)


def test_effects_are_on_or_off_by_name():
    from graphcal.simulation.effects import build_effects

    assert [e.name for e in build_effects({})] == ["intra_sweep_motion"]  # on by default
    assert [e.name for e in build_effects({"time_offset": {"offset_s": 0.01}})] == ["intra_sweep_motion",
                                                                                    "time_offset"]
    assert build_effects({"intra_sweep_motion": False}) == []


def test_recorded_trajectory_covers_the_returns_at_any_ins_rate(tmp_path):
    rec = simulate(small(duration_s=3.4, ins=InsErrors(rate_hz=1.0)), quiet=True)
    rec.save(tmp_path / "rec")
    assert graphcal.Recording.load(tmp_path / "rec").trajectory.time[-1] == pytest.approx(1003.4)


def test_public_api():
    assert graphcal.simulate is simulate and graphcal.Recording.load
