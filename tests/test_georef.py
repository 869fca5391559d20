"""Georeferencing (graphcal.recording.geodesy) and pose interpolation (graphcal.recording.poses) against pyproj,
closed-form transverse Mercator and analytic motion."""

from __future__ import annotations

import numpy as np
import pytest
from pyproj import CRS, Geod, Transformer
from scipy.spatial.transform import Rotation

import graphcal
from graphcal import Recording, RecordingError
from graphcal.recording.geodesy import (
    geodetic_to_grid,
    grid_to_geodetic,
    map_factors,
    resolve_crs,
    to_world,
    utm_crs,
)
from graphcal.recording.poses import PoseTrack
from graphcal.simulation.drive import Drive, straight, turn
from graphcal.simulation.scenario import Scenario
from graphcal.simulation.scene import street
from graphcal.recording.trajectory import Trajectory

A_WGS84, F_WGS84, K0_UTM = 6378137.0, 1 / 298.257223563, 0.9996
PARIS = (48.8566, 2.3522)
KARLSRUHE = (49.0, 8.4)
FAR_EAST_ZONE_31 = (60.0, 5.9)  # 2.9 deg east of the central meridian of zone 31 (3 deg E)


def utm_forward(lat_deg: float, lon_deg: float, zone: int, south: bool = False):
    """Closed-form UTM (Krueger series to n^3, sub-mm in a zone): easting, northing [m],
    scale k, convergence gamma [deg, counter-clockwise from grid north to true north]."""
    n = F_WGS84 / (2 - F_WGS84)
    a_rect = A_WGS84 / (1 + n) * (1 + n**2 / 4 + n**4 / 64)
    alpha = np.array([n / 2 - 2 * n**2 / 3 + 5 * n**3 / 16, 13 * n**2 / 48 - 3 * n**3 / 5, 61 * n**3 / 240])
    phi, dlam = np.radians(lat_deg), np.radians(lon_deg - (6 * zone - 183))
    c = 2 * np.sqrt(n) / (1 + n)
    t = np.sinh(np.arctanh(np.sin(phi)) - c * np.arctanh(c * np.sin(phi)))
    xi, eta = np.arctan2(t, np.cos(dlam)), np.arctanh(np.sin(dlam) / np.sqrt(1 + t**2))
    j = np.arange(1, 4)
    easting = 500000 + K0_UTM * a_rect * (eta + np.sum(alpha * np.cos(2 * j * xi) * np.sinh(2 * j * eta)))
    northing = (1e7 if south else 0.0) + K0_UTM * a_rect * (xi + np.sum(alpha * np.sin(2 * j * xi)
                                                                          * np.cosh(2 * j * eta)))
    sigma = 1 + np.sum(2 * j * alpha * np.cos(2 * j * xi) * np.cosh(2 * j * eta))
    tau = np.sum(2 * j * alpha * np.sin(2 * j * xi) * np.sinh(2 * j * eta))
    k = K0_UTM * a_rect / A_WGS84 * np.sqrt((1 + ((1 - n) / (1 + n) * np.tan(phi)) ** 2) * (sigma**2 + tau**2)
                                            / (t**2 + np.cos(dlam) ** 2))
    s = np.sqrt(1 + t**2)
    gamma = np.degrees(np.arctan2(tau * s + sigma * t * np.tan(dlam), sigma * s - tau * t * np.tan(dlam)))
    return easting, northing, k, gamma


def project(crs, lat, lon, alt=0.0) -> np.ndarray:
    """pyproj directly (not through graphcal): WGS84 3D -> crs, x y z."""
    transformer = Transformer.from_crs("EPSG:4979", crs, always_xy=True)
    lon, lat, alt = (np.array(v, dtype=float) for v in np.broadcast_arrays(np.atleast_1d(lon), lat, alt))
    return np.column_stack(transformer.transform(lon, lat, alt))


def convergence_by_finite_difference(crs, lat, lon, step_deg=1e-5) -> float:
    """Grid direction of true north: project two points of the same meridian, a step apart,
    and measure the angle from grid north (y) to the chord, counter-clockwise positive [deg]."""
    south, north = project(crs, [lat - step_deg, lat + step_deg], [lon, lon])[:, :2]
    dx, dy = north - south
    return float(np.degrees(np.arctan2(-dx, dy)))


def scale_by_finite_difference(crs, lat, lon, step_deg=1e-4) -> float:
    """Grid distance / geodesic distance of a short east-west segment."""
    a, b = project(crs, [lat, lat], [lon - step_deg, lon + step_deg])[:, :2]
    _, _, true_distance = Geod(ellps="WGS84").inv(lon - step_deg, lat, lon + step_deg, lat)
    return float(np.linalg.norm(b - a) / true_distance)


def geodetic_track(lat, lon, rpy=None) -> Trajectory:
    """A lat/lon trajectory at 1 Hz, 100 m ellipsoidal height, attitude relative to ENU."""
    lat, lon = np.asarray(lat, dtype=float), np.asarray(lon, dtype=float)
    n = len(lat)
    return Trajectory(time=np.arange(n, dtype=float), position=np.column_stack([lat, lon, np.full(n, 100.0)]),
                      rpy_deg=np.zeros((n, 3)) if rpy is None else np.asarray(rpy, dtype=float), geodetic=True)


def rz(deg):
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def ry(deg):
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rx(deg):
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def angle_deg(a: Rotation, b: Rotation) -> np.ndarray:
    return np.degrees((a.inv() * b).magnitude())


# --- projection, zone, map factors -----------------------------------------------------------
def test_geodetic_to_grid_paris():
    crs = CRS.from_epsg(32631)
    got = geodetic_to_grid(crs, np.array([PARIS[0]]), np.array([PARIS[1]]), np.array([35.0]))
    np.testing.assert_allclose(got, project(crs, *PARIS, 35.0), rtol=0, atol=1e-6)
    # hand-coded value, verified with the closed-form series below (independent of PROJ)
    np.testing.assert_allclose(got[0], [452482.533, 5411717.177, 35.0], rtol=0, atol=1e-3)
    easting, northing, _, _ = utm_forward(*PARIS, zone=31)
    np.testing.assert_allclose(got[0, :2], [easting, northing], rtol=0, atol=1e-4)


def test_grid_to_geodetic_inverts():
    crs = CRS.from_epsg(32632)
    lat = KARLSRUHE[0] + np.linspace(-0.5, 0.5, 11)
    lon = KARLSRUHE[1] + np.linspace(-2.0, 2.0, 11)
    alt = np.linspace(-20.0, 900.0, 11)
    back = grid_to_geodetic(crs, geodetic_to_grid(crs, lat, lon, alt))
    np.testing.assert_allclose(back, np.column_stack([lat, lon, alt]), rtol=0, atol=1e-9)


@pytest.mark.parametrize("lat, lon, epsg", [
    (*PARIS, 32631),
    (*KARLSRUHE, 32632),
    (-8.84, 13.23, 32733),  # Luanda
    (-33.92, 18.42, 32734),  # Cape Town
    (40.71, -74.01, 32618),  # New York
    (35.68, 139.69, 32654),  # Tokyo
], ids=["paris", "karlsruhe", "luanda", "cape-town", "new-york", "tokyo"])
def test_utm_crs(lat, lon, epsg):
    crs = utm_crs(lat, lon)
    assert crs.to_epsg() == epsg
    zone = int((lon + 180) // 6) + 1
    assert epsg % 100 == zone and (epsg // 100 == 327) == (lat < 0)


@pytest.mark.parametrize("lat", [85.0, -82.0])
def test_utm_crs_outside_utm(lat):
    with pytest.raises(ValueError, match="UTM"):
        utm_crs(lat, 10.0)


@pytest.mark.parametrize("lon_start, lon_end, epsg", [(5.999, 6.2, 32631), (6.001, 5.8, 32632)])
def test_auto_crs_is_the_zone_of_the_first_fix(lon_start, lon_end, epsg):
    """A drive crossing the 6 deg E zone boundary: the zone of its first fix, whatever the rest."""
    lon = np.linspace(lon_start, lon_end, 50)
    trajectory = geodetic_track(np.full(50, 50.0), lon)
    assert resolve_crs("auto", trajectory).to_epsg() == epsg
    world = to_world(trajectory, "auto")
    assert world.crs.to_epsg() == epsg
    np.testing.assert_allclose(world.poses.position_m, project(CRS.from_epsg(epsg), 50.0, lon, 100.0),
                               rtol=0, atol=1e-6)


def test_auto_crs_in_a_recording(tmp_path):
    recording = graphcal.simulate(scenario("geodetic"), quiet=True)
    recording.crs = "auto"
    loaded = Recording.load(recording.save(tmp_path / "rec"))
    assert loaded.crs == "auto" and loaded.world.crs.to_epsg() == 32631


def test_auto_crs_beyond_utm_is_a_recording_error():
    with pytest.raises(RecordingError, match=r"recording.yaml, field 'crs': crs is 'auto' but the first fix "
                                             r"\(lat 84.5, lon 10\) is outside the UTM zones.*expected an explicit"):
        resolve_crs("auto", geodetic_track([84.5, 84.6], [10.0, 10.0]), "recording.yaml")


@pytest.mark.parametrize("lat, lon, epsg, about_deg", [
    (*FAR_EAST_ZONE_31, 32631, 2.512),
    (*KARLSRUHE, 32632, -0.453),
    (*PARIS, 32631, -0.488),
    (-33.92, 18.42, 32734, 1.440),  # southern hemisphere, west of the central meridian (21 deg E)
])
def test_meridian_convergence(lat, lon, epsg, about_deg):
    crs = CRS.from_epsg(epsg)
    _, gamma = map_factors(crs, lon, lat)
    independent = convergence_by_finite_difference(crs, lat, lon)
    assert abs(gamma - independent) < 1e-6
    assert abs(gamma - utm_forward(lat, lon, epsg % 100, south=epsg > 32700)[3]) < 1e-7
    # first-order spherical value tan(gamma) = tan(dlon) sin(lat)
    dlon = np.radians(lon - (6 * (epsg % 100) - 183))
    assert abs(gamma - np.degrees(np.arctan(np.tan(dlon) * np.sin(np.radians(lat))))) < 2e-3
    assert gamma == pytest.approx(about_deg, abs=1e-3)


@pytest.mark.parametrize("lat, lon, epsg", [(*FAR_EAST_ZONE_31, 32631), (*KARLSRUHE, 32632), (*PARIS, 32631)])
def test_scale_factor(lat, lon, epsg):
    crs = CRS.from_epsg(epsg)
    k, _ = map_factors(crs, lon, lat)
    dlon = np.radians(lon - (6 * (epsg % 100) - 183))
    assert abs(k - K0_UTM * (1 + (dlon * np.cos(np.radians(lat))) ** 2 / 2)) < 1e-6
    assert abs(k - utm_forward(lat, lon, epsg % 100)[2]) < 1e-9
    assert abs(k - scale_by_finite_difference(crs, lat, lon)) < 1e-8


@pytest.mark.parametrize("code, lat, lon", [
    ("EPSG:2154", 45.0, 7.5),  # Lambert-93 (conic), far from its central meridian 3 deg E
    ("EPSG:3006", 63.0, 20.0),  # SWEREF99 TM: axes in northing, easting order
    ("EPSG:3035", 60.0, 25.0),  # LAEA Europe: not conformal, northing first
])
def test_other_projections(code, lat, lon):
    """Map factors and world poses of non-UTM grids, whatever the CRS's axis order."""
    crs = resolve_crs(code, geodetic_track([lat, lat], [lon, lon]))
    k, gamma = map_factors(crs, lon, lat)
    independent = convergence_by_finite_difference(crs, lat, lon)
    assert abs(independent) > 3.0 and abs(gamma - independent) < 1e-6
    if code != "EPSG:3035":  # LAEA's scale differs along and across the meridian
        assert abs(k - scale_by_finite_difference(crs, lat, lon)) < 1e-8
    lat_track = lat + np.linspace(0.0, 0.001, 5)
    world = to_world(geodetic_track(lat_track, np.full(5, lon), rpy=np.tile([0.0, 0.0, 90.0], (5, 1))), code)
    xyz = project(crs, lat_track, lon, 100.0)
    np.testing.assert_allclose(world.poses.position_m, xyz, rtol=0, atol=1e-6)
    assert xyz[-1, 1] - xyz[0, 1] > 100.0  # y is the grid northing
    gamma_track = [convergence_by_finite_difference(crs, la, lon) for la in lat_track]
    np.testing.assert_allclose(world.poses.rpy_deg[:, 2], 90.0 + np.array(gamma_track), rtol=0, atol=1e-6)


def test_map_factors_vectorised():
    crs = CRS.from_epsg(32631)
    lat, lon = np.linspace(40.0, 60.0, 5), np.linspace(0.5, 5.5, 5)
    k, gamma = map_factors(crs, lon, lat)
    assert k.shape == gamma.shape == (5,)
    for i in range(5):
        assert abs(gamma[i] - convergence_by_finite_difference(crs, lat[i], lon[i])) < 1e-6
        assert abs(k[i] - scale_by_finite_difference(crs, lat[i], lon[i])) < 1e-8


# --- to_world ---------------------------------------------------------------------------------
def test_to_world_heading_true_north_far_from_the_central_meridian():
    """A vehicle driving due north along the 5.9 deg E meridian at 60 deg N, in zone 31."""
    lat0, lon = FAR_EAST_ZONE_31
    lat = lat0 + np.linspace(0.0, 0.002, 21)  # ~220 m north
    roll, pitch = 2.0, -3.0
    rpy = np.tile([roll, pitch, 90.0], (21, 1))
    world = to_world(geodetic_track(lat, np.full(21, lon), rpy=rpy), "EPSG:32631")
    crs = CRS.from_epsg(32631)
    gamma = np.array([convergence_by_finite_difference(crs, la, lon) for la in lat])
    assert 2.5 < gamma.min() and gamma.max() < 2.52

    np.testing.assert_allclose(world.poses.position_m, project(crs, lat, np.full(21, lon), 100.0), rtol=0, atol=1e-6)
    np.testing.assert_allclose(world.convergence_deg, gamma, rtol=0, atol=1e-6)
    np.testing.assert_allclose(world.poses.rpy_deg[:, 2], 90.0 + gamma, rtol=0, atol=1e-6)
    np.testing.assert_allclose(world.poses.rpy_deg[:, :2], np.tile([roll, pitch], (21, 1)), rtol=0, atol=1e-9)
    # R_grid_body = Rz(gamma) R_enu_body, R_enu_body = Rz(yaw) Ry(pitch) Rx(roll), spelt out
    for i in (0, 10, 20):
        expected = rz(gamma[i]) @ rz(90.0) @ ry(pitch) @ rx(roll)
        np.testing.assert_allclose(world.poses.rotation[i].as_matrix(), expected, rtol=0, atol=1e-8)
    # the vehicle moves where its nose points: the grid track follows the projected meridian
    step = np.diff(world.poses.position_m[:, :2], axis=0)
    track_deg = np.degrees(np.arctan2(step[:, 1], step[:, 0]))
    yaw_mid = (world.poses.rpy_deg[1:, 2] + world.poses.rpy_deg[:-1, 2]) / 2
    np.testing.assert_allclose(track_deg, yaw_mid, rtol=0, atol=1e-5)
    k, _ = map_factors(crs, np.full(21, lon), lat)
    np.testing.assert_allclose(world.scale_factor, k, rtol=0, atol=1e-12)


def test_to_world_projected_keeps_grid_poses():
    crs = CRS.from_epsg(32632)
    lat, lon = KARLSRUHE
    xyz = project(crs, lat, lon, 120.0)[0] + np.array([[0.0, 0.0, 0.0], [10.0, 5.0, 0.1], [20.0, 5.0, 0.2]])
    rpy = np.array([[0.0, 0.0, 10.0], [1.0, 0.5, 20.0], [0.0, 0.0, 30.0]])
    world = to_world(Trajectory(np.array([0.0, 1.0, 2.0]), xyz, rpy, geodetic=False), "EPSG:32632")
    np.testing.assert_array_equal(world.poses.position_m, xyz)
    np.testing.assert_allclose(world.poses.rpy_deg, rpy, rtol=0, atol=1e-9)
    assert abs(world.convergence_deg[0] - convergence_by_finite_difference(crs, lat, lon)) < 1e-6


def scenario(trajectory_format: str, origin_m=(448000.0, 5411000.0, 50.0)) -> Scenario:
    return Scenario(name="t", duration_s=1.0, size=0.1, scene=street(60, 16),
                    drive=Drive(segments=straight(2) + turn(15, 20), speed_knots=[(0, 5.0)]),
                    trajectory_format=trajectory_format, origin_m=origin_m)


@pytest.mark.parametrize("origin_m", [(448000.0, 5411000.0, 50.0), (661700.0, 6654950.0, 20.0)],
                         ids=["paris", "far-east-60n"])
def test_geodetic_and_projected_recordings_agree(tmp_path, origin_m):
    """The same drive written as lat/lon and as grid coordinates gives the same world poses,
    also after a save/load round trip of both."""
    projected = graphcal.simulate(scenario("projected", origin_m), quiet=True)
    geodetic = graphcal.simulate(scenario("geodetic", origin_m), quiet=True)
    assert geodetic.trajectory.geodetic and not projected.trajectory.geodetic
    assert np.abs(geodetic.world.convergence_deg).min() > 0.4  # the conversion matters
    for a, b in [(projected, geodetic),
                 (Recording.load(projected.save(tmp_path / "p")), Recording.load(geodetic.save(tmp_path / "g")))]:
        pa_, pb = a.world.poses, b.world.poses
        np.testing.assert_array_equal(pa_.time, pb.time)
        assert np.abs(pa_.position_m - pb.position_m).max() < 1e-4
        assert angle_deg(pa_.rotation, pb.rotation).max() < 1e-6
        np.testing.assert_allclose(a.world.convergence_deg, b.world.convergence_deg, rtol=0, atol=1e-9)
        np.testing.assert_allclose(a.world.scale_factor, b.world.scale_factor, rtol=0, atol=1e-9)
    # and the geodetic file's yaw is the grid yaw minus the convergence
    np.testing.assert_allclose(geodetic.trajectory.rpy_deg[:, 2],
                               projected.trajectory.rpy_deg[:, 2] - geodetic.world.convergence_deg,
                               rtol=0, atol=1e-6)


# --- PoseTrack.interpolate --------------------------------------------------------------------
OMEGA = np.radians(40.0)  # yaw rate [rad/s]
ROLL, PITCH = 3.0, -2.0


def circle(t):
    """Position [m] on a 12 m circle at the yaw rate, climbing 0.5 m/s."""
    return np.column_stack([12 * np.cos(OMEGA * t), 12 * np.sin(OMEGA * t), 0.5 * t])


def true_rotation(t) -> Rotation:
    """R = Rz(omega t) Ry(pitch) Rx(roll): between 10 Hz samples SLERP is exact (one fixed axis)."""
    return Rotation.from_matrix(np.stack([rz(np.degrees(OMEGA * ti)) @ ry(PITCH) @ rx(ROLL) for ti in t]))


@pytest.fixture(scope="module")
def track() -> PoseTrack:
    t = 500.0 + np.arange(0.0, 20.0 + 1e-9, 0.1)  # 10 Hz, 20 s: 800 deg of yaw
    yaw = np.degrees(OMEGA * (t - 500.0))
    rpy = np.column_stack([np.full_like(t, ROLL), np.full_like(t, PITCH), yaw])
    return PoseTrack.from_rpy(t, circle(t - 500.0), rpy)


def test_from_rpy_convention(track):
    np.testing.assert_allclose(track.rotation.as_matrix(), true_rotation(track.time - 500.0).as_matrix(),
                               rtol=0, atol=1e-12)


def test_interpolate_at_random_times(track):
    rng = np.random.default_rng(7)
    t = np.sort(rng.uniform(*track.span, 2000))
    position, rotation = track.interpolate(t)
    assert position.shape == (2000, 3) and len(rotation) == 2000
    expected = np.column_stack([np.interp(t, track.time, track.position_m[:, k]) for k in range(3)])
    np.testing.assert_allclose(position, expected, rtol=0, atol=1e-9)
    assert angle_deg(rotation, true_rotation(t - 500.0)).max() < 1e-9
    # analytic yaw (unwrapped by whole turns), roll and pitch constant
    rpy = rotation.as_euler("ZYX", degrees=True)[:, ::-1]
    yaw_error = (rpy[:, 2] - np.degrees(OMEGA * (t - 500.0)) + 180.0) % 360.0 - 180.0
    assert np.abs(yaw_error).max() < 1e-9
    np.testing.assert_allclose(rpy[:, :2], np.tile([ROLL, PITCH], (2000, 1)), rtol=0, atol=1e-9)


def test_interpolate_at_the_samples_and_the_ends(track):
    position, rotation = track.interpolate(track.time)
    np.testing.assert_allclose(position, track.position_m, rtol=0, atol=1e-12)
    assert angle_deg(rotation, track.rotation).max() < 1e-9
    midpoints = (track.time[:-1] + track.time[1:]) / 2
    position, _ = track.interpolate(midpoints)
    np.testing.assert_allclose(position, (track.position_m[:-1] + track.position_m[1:]) / 2, rtol=0, atol=1e-12)


def test_interpolate_a_million_timestamps(track):
    rng = np.random.default_rng(11)
    t = rng.uniform(*track.span, 1_000_000)
    position, rotation = track.interpolate(t)
    assert position.shape == (1_000_000, 3) and len(rotation) == 1_000_000
    subset = rng.choice(1_000_000, 500, replace=False)
    expected = np.column_stack([np.interp(t[subset], track.time, track.position_m[:, k]) for k in range(3)])
    np.testing.assert_allclose(position[subset], expected, rtol=0, atol=1e-9)
    assert angle_deg(rotation[subset], true_rotation(t[subset] - 500.0)).max() < 1e-9


def test_transform_and_resample(track):
    t = np.array([500.05, 507.33, 519.99])
    p_body = np.array([[1.0, 0.0, 0.0], [0.0, 2.0, 0.5], [-1.0, 1.0, 2.0]])
    position, _ = track.interpolate(t)
    expected = np.einsum("nij,nj->ni", true_rotation(t - 500.0).as_matrix(), p_body) + position
    np.testing.assert_allclose(track.transform(t, p_body), expected, rtol=0, atol=1e-9)
    resampled = track.resample(t)
    np.testing.assert_array_equal(resampled.time, t)
    assert angle_deg(resampled.rotation, true_rotation(t - 500.0)).max() < 1e-9


def test_interpolate_refuses_times_outside_the_span(track):
    start, end = track.span
    with pytest.raises(ValueError, match="outside the poses' span"):
        track.interpolate(np.array([start, end + 0.01]))
    position, rotation = track.interpolate(start)  # a scalar time is one pose
    np.testing.assert_allclose(position, track.position_m[:1])
    assert len(rotation) == 1
