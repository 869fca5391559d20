"""tools/foreign_sim: an independent simulator's recordings load in graphcal, and their raw returns,
put back together with the truth files by a small re-implementation of the contract's formula,
lie on the simulator's own scene surfaces (and agree with graphcal's georeferencing)."""

from __future__ import annotations

import ast
import csv
import subprocess
import sys
from pathlib import Path

import numpy as np
import open3d as o3d
import pyarrow.parquet as pq
import pytest
import yaml

from tools.foreign_sim import FAMILIES, Departures, simulate

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "tools" / "foreign_sim"
GROUND = 0  # tools.foreign_sim.mesh.GROUND
FLAT_FAMILIES = ("box_street", "relief_street")  # the road surface is the plane z = 0 (layout)


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    """One short, noise-free recording per family (range noise and encoder jitter off)."""
    base = tmp_path_factory.mktemp("foreign")
    return {family: simulate(family, base / family, duration_s=3.0, size=0.02, seed=11 + k,
                             mount="tilted" if k % 2 else "level", range_noise_m=0.0, encoder_jitter_deg=0.0)
            for k, family in enumerate(FAMILIES)}


# --- an own, small re-implementation of the contract (RECORDING.md) ----------------------------------
def rot_rpy(rpy_deg) -> np.ndarray:
    """(..., 3) roll, pitch, yaw [deg] -> (..., 3, 3) R = Rz(yaw) Ry(pitch) Rx(roll)."""
    r, p, y = np.moveaxis(np.radians(np.asarray(rpy_deg, dtype=np.float64)), -1, 0)
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.stack([np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1),
                     np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1),
                     np.stack([-sp, cp * sr, cp * cr], -1)], -2)


def quat_of(R: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotation matrices -> (N, 4) unit quaternions (w, x, y, z), w >= 0."""
    w = np.sqrt(np.maximum(1.0 + R[:, 0, 0] + R[:, 1, 1] + R[:, 2, 2], 1e-12)) / 2.0
    q = np.column_stack([w, (R[:, 2, 1] - R[:, 1, 2]) / (4 * w), (R[:, 0, 2] - R[:, 2, 0]) / (4 * w),
                         (R[:, 1, 0] - R[:, 0, 1]) / (4 * w)])
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def rot_of_quat(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q.T
    return np.stack([np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
                     np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
                     np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], -2)


def read_csv(path: Path) -> tuple[list[str], np.ndarray]:
    with open(path, newline="") as handle:
        rows = list(csv.reader(handle))
    return rows[0], np.array(rows[1:], dtype=np.float64)


def world_points(directory: Path) -> tuple[np.ndarray, dict]:
    """Raw returns -> world xyz with the TRUE offsets, extrinsic and trajectory (eq. 4.2, then
    p_body = R p_lidar + T, then p_world = R_nav(t) p_body + X_nav(t), linear + slerp in time)."""
    table = pq.read_table(directory / "points.parquet").to_pydict()
    t = np.asarray(table["time"])
    fibre = np.asarray(table["fibre"], dtype=np.int64)
    rho = np.asarray(table["range"], dtype=np.float64)
    theta = np.asarray(table["azimuth"], dtype=np.float64)
    sensor = yaml.safe_load((directory / "sensor.yaml").read_text())
    phi = np.radians([f["elevation_deg"] for f in sensor["fibres"]])
    header, intr = read_csv(directory / "truth" / "intrinsics.csv")
    assert header == ["fibre", "d_range_m", "d_azimuth_deg", "d_elevation_deg", "h_z_m"]
    d_rho, d_theta, d_phi, h_z = intr[fibre, 1], np.radians(intr[fibre, 2]), np.radians(intr[fibre, 3]), intr[fibre, 4]
    r, a, e = rho + d_rho, theta + d_theta, phi[fibre] + d_phi
    p_lidar = np.column_stack([r * np.cos(a) * np.cos(e), -r * np.sin(a) * np.cos(e), r * np.sin(e) + h_z])
    ext = yaml.safe_load((directory / "truth" / "extrinsic.yaml").read_text())
    p_body = p_lidar @ rot_rpy(ext["boresight_deg"]).T + np.asarray(ext["lever_arm_m"])
    header, traj = read_csv(directory / "truth" / "trajectory.csv")
    assert header == ["time", "x", "y", "z", "roll", "pitch", "yaw"]
    k = np.clip(np.searchsorted(traj[:, 0], t, side="right") - 1, 0, len(traj) - 2)
    u = (t - traj[k, 0]) / (traj[k + 1, 0] - traj[k, 0])
    assert u.min() >= 0 and u.max() <= 1
    position = (1 - u)[:, None] * traj[k, 1:4] + u[:, None] * traj[k + 1, 1:4]
    q0, q1 = quat_of(rot_rpy(traj[k, 4:7])), quat_of(rot_rpy(traj[k + 1, 4:7]))
    q1 = np.where((np.sum(q0 * q1, axis=1) < 0)[:, None], -q1, q1)
    omega = np.arccos(np.clip(np.sum(q0 * q1, axis=1), -1.0, 1.0))
    small = omega < 1e-9
    s = np.where(small, 1.0, np.sin(omega))
    w0 = np.where(small, 1 - u, np.sin((1 - u) * omega) / s)
    w1 = np.where(small, u, np.sin(u * omega) / s)
    R_nav = rot_of_quat(w0[:, None] * q0 + w1[:, None] * q1)
    return np.einsum("nij,nj->ni", R_nav, p_body) + position, table


def closest_on_triangles(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(N, 3) closest points of triangles (a, b, c) to points p, in float64 (Ericson, Real-Time
    Collision Detection, 5.1.5), vectorised."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = np.einsum("ij,ij->i", ab, ap), np.einsum("ij,ij->i", ac, ap)
    bp, cp = p - b, p - c
    d3, d4 = np.einsum("ij,ij->i", ab, bp), np.einsum("ij,ij->i", ac, bp)
    d5, d6 = np.einsum("ij,ij->i", ab, cp), np.einsum("ij,ij->i", ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v_in, w_in = vb / denom, vc / denom
        w_ab = d1 / (d1 - d3)
        w_ac = d2 / (d2 - d6)
        w_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
    out = a + v_in[:, None] * ab + w_in[:, None] * ac  # inside the face
    cases = [(vc <= 0) & (d1 >= 0) & (d3 <= 0), a + w_ab[:, None] * ab,        # edge ab
             (vb <= 0) & (d2 >= 0) & (d6 <= 0), a + w_ac[:, None] * ac,        # edge ac
             (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), b + w_bc[:, None] * (c - b)]  # edge bc
    for mask, point in zip(cases[4::-2], cases[5::-2]):
        out = np.where(mask[:, None], point, out)
    for mask, point in (((d6 >= 0) & (d5 <= d6), c), ((d3 >= 0) & (d4 <= d3), b), ((d1 <= 0) & (d2 <= 0), a)):
        out = np.where(mask[:, None], point, out)
    return out


def distance_to_scene(scene, local: np.ndarray, fallback: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """(distance [m], primitive id) of each point to the mesh: open3d proposes the closest
    triangle (float32), the distance to it is then computed exactly in float64; the few points
    that are not within 0.1 mm of their proposal are checked against every triangle."""
    caster = o3d.t.geometry.RaycastingScene()
    caster.add_triangles(o3d.core.Tensor(scene["vertices"].astype(np.float32)),
                         o3d.core.Tensor(scene["triangles"].astype(np.uint32)))
    prim = caster.compute_closest_points(o3d.core.Tensor(local.astype(np.float32)))["primitive_ids"].numpy()
    V, T = scene["vertices"], scene["triangles"]
    a, b, c = (V[T[prim, k]] for k in range(3))
    distance = np.linalg.norm(closest_on_triangles(local, a, b, c) - local, axis=1)
    for i in np.flatnonzero(distance > 1e-4)[:200] if fallback else ():
        p = np.broadcast_to(local[i], (len(T), 3))
        all_d = np.linalg.norm(closest_on_triangles(p, V[T[:, 0]], V[T[:, 1]], V[T[:, 2]]) - p, axis=1)
        prim[i] = int(np.argmin(all_d))
        distance[i] = all_d[prim[i]]
    return distance, prim


def to_layout(directory: Path, xyz: np.ndarray) -> np.ndarray:
    scene = np.load(directory / "truth" / "scene.npz")
    h = np.radians(float(scene["heading_deg"]))
    d = xyz - scene["origin"]
    return np.column_stack([np.cos(h) * d[:, 0] + np.sin(h) * d[:, 1], -np.sin(h) * d[:, 0] + np.cos(h) * d[:, 1],
                            d[:, 2]])


# --- tests ------------------------------------------------------------------------------------------
def test_simulator_source_imports_nothing_from_graphcal():
    sources = sorted(PACKAGE.rglob("*.py"))
    assert len(sources) >= 5
    for source in sources:
        tree = ast.parse(source.read_text(), filename=str(source))
        for node in ast.walk(tree):
            names = []
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                names = [node.module or ""]
            elif isinstance(node, ast.Call) and getattr(node.func, "attr", getattr(node.func, "id", "")) in (
                    "import_module", "__import__"):
                names = [arg.value for arg in node.args if isinstance(arg, ast.Constant) and isinstance(arg.value, str)]
            for name in names:
                assert name.split(".")[0] not in ("graphcal", "factors"), f"{source.name} imports {name}"


@pytest.mark.parametrize("family", FAMILIES)
def test_recording_loads_in_graphcal(recordings, family):
    import graphcal

    directory = recordings[family]
    rec = graphcal.Recording.load(directory)
    summary = rec.validate()
    assert rec.crs == "EPSG:32631" and rec.sensor.model == "HDL-32E" and rec.sensor.reference_fibre == 15
    assert summary.n_points > 20_000 and (summary.count_per_fibre > 0).all()
    assert 2.9 < summary.time_max - summary.time_min <= 3.0
    np.testing.assert_allclose(rec.sensor.elevation_deg, graphcal.sensor_from_catalog("HDL-32E").elevation_deg)
    truth = rec.truth
    assert truth.intrinsics.shape == (32, 4) and np.all(truth.intrinsics[15] == 0)
    assert np.abs(truth.intrinsics[:, 0]).max() <= 0.03 and np.degrees(np.abs(truth.intrinsics[:, 1])).max() <= 0.3
    assert "intra_sweep_motion" in truth.effects and "encoder_jitter" not in truth.effects
    assert len(truth.world_points()) == summary.n_points
    columns = rec.points.read(["time", "scan", "azimuth"])
    assert np.all(np.diff(columns["time"]) >= 0)
    assert 0 <= columns["azimuth"].min() and columns["azimuth"].max() <= 2 * np.pi + 1e-6
    assert columns["scan"].max() - columns["scan"].min() in (29, 30, 31)
    graphcal_bin = Path(sys.executable).parent / "graphcal"
    result = subprocess.run([str(graphcal_bin), "info", str(directory)], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert "HDL-32E" in result.stdout and "truth: yes" in result.stdout


@pytest.mark.parametrize("family", FAMILIES)
def test_returns_lie_on_the_scene(recordings, family):
    """Without noise, the returns rebuilt with the true parameters are on the meshes (< 1 mm)."""
    directory = recordings[family]
    xyz, table = world_points(directory)
    truth = pq.read_table(directory / "truth" / "points.parquet").to_pydict()
    true_xyz = np.column_stack([truth["x"], truth["y"], truth["z"]])
    assert np.abs(xyz - true_xyz).max() < 1e-4  # float32 range/azimuth and CSV rounding only
    scene = np.load(directory / "truth" / "scene.npz")
    local = to_layout(directory, xyz)
    distance, prim = distance_to_scene(scene, local)
    assert distance.max() < 1e-3, f"{np.sum(distance >= 1e-3)} returns off the scene, max {distance.max():.4f} m"
    assert np.median(distance) < 1e-5
    material = scene["material"][prim]
    assert 0.1 < np.mean(material == GROUND) < 0.9  # ground and objects both seen
    if family in FLAT_FAMILIES:
        on_road = material == GROUND
        assert np.abs(local[on_road, 2]).max() < 1e-3
    rho = np.asarray(table["range"])
    assert rho.min() >= 1.0 and rho.max() <= 100.0


@pytest.mark.parametrize("family", ["relief_street", "suburb"])
def test_graphcal_georeferencing_agrees(recordings, family):
    """graphcal's own chain (sensor model, extrinsic, interpolated poses) with the true values
    gives the same world points as the small re-implementation above."""
    import graphcal
    from graphcal.recording.geodesy import to_world
    from graphcal.recording.georeference import georeference

    directory = recordings[family]
    rec = graphcal.Recording.load(directory)
    truth = rec.truth
    poses = to_world(truth.trajectory, rec.crs).poses
    data = rec.points.read(["time", "fibre", "range", "azimuth"])
    theirs = georeference(data["time"], data["fibre"], data["range"], data["azimuth"], rec.sensor,
                          truth.extrinsic, poses, truth.intrinsics)
    ours, _ = world_points(directory)
    assert np.abs(theirs - ours).max() < 1e-3


def test_noise_seed_and_size(tmp_path):
    """Same seed, same recording; another size keeps the truth (scene, offsets, mounting) and
    draws a subset of the firing blocks; the default noise moves returns off the surfaces by
    about the range noise."""
    a = simulate("box_street", tmp_path / "a", duration_s=1.0, size=0.01, seed=5)
    b = simulate("box_street", tmp_path / "b", duration_s=1.0, size=0.01, seed=5)
    c = simulate("box_street", tmp_path / "c", duration_s=1.0, size=0.03, seed=5)
    ta, tb, tc = (pq.read_table(d / "points.parquet") for d in (a, b, c))
    assert ta.equals(tb)
    assert 2.0 < tc.num_rows / ta.num_rows < 4.0
    for name in ("intrinsics.csv", "extrinsic.yaml", "trajectory.csv"):
        assert (a / "truth" / name).read_text() == (c / "truth" / name).read_text()
    assert (a / "trajectory.csv").read_text() == (c / "trajectory.csv").read_text()
    xyz, _ = world_points(a)
    local = to_layout(a, xyz)
    distance, _ = distance_to_scene(np.load(a / "truth" / "scene.npz"), local, fallback=False)
    assert 0.0015 < np.median(distance) < 0.012 and distance.max() > 0.02  # 1 cm range noise, jitter
    header, ins = read_csv(a / "trajectory.csv")
    _, true = read_csv(a / "truth" / "trajectory.csv")
    assert np.allclose(np.diff(ins[:, 0]), 0.005)  # 200 Hz INS
    matched = true[np.searchsorted(true[:, 0], ins[:, 0] - 1e-7)]
    assert 0.003 < np.std(ins[:, 1:4] - matched[:, 1:4]) < 0.007  # 5 mm white noise


def test_a_scan_is_cut_where_the_reading_first_wraps():
    """A firing read just behind the wrap after another read past it (the encoder's per-revolution jitter)
    stays in the new scan, so that returns stamped with their scan's start stay in time order; its azimuth is
    its reading, near 360 deg."""
    from tools.foreign_sim.simulation import scans

    two_pi = 2 * np.pi
    reading = np.array([two_pi - 1e-3, two_pi + 1e-5, two_pi - 2e-5, two_pi + 2e-3, 2 * two_pi + 1e-3])
    np.testing.assert_array_equal(scans(reading), [0, 1, 1, 1, 2])
    np.testing.assert_array_equal(scans(reading[2:], last_scan=1.0), [1, 1, 2])  # the cut carried across chunks


def test_drive_dynamics_of_a_full_drive(tmp_path):
    """The default 15 s box_street drive: speed changes 6 -> 9 -> 4 -> 8 m/s, a left turn at up to
    ~29 deg/s, pitch from braking, roll from the turn (truth trajectory at 1 kHz)."""
    directory = simulate("box_street", tmp_path / "full", duration_s=15.0, size=0.001, seed=2)
    _, true = read_csv(directory / "truth" / "trajectory.csv")
    t, xy, rpy = true[:, 0], true[:, 1:3], true[:, 4:7]
    speed = np.linalg.norm(np.diff(xy, axis=0), axis=1) / np.diff(t)
    assert 5.9 < speed[:500].mean() < 6.1 and speed.max() == pytest.approx(9.0, abs=0.05)
    assert speed.min() == pytest.approx(4.0, abs=0.05) and speed[-500:].mean() == pytest.approx(8.0, abs=0.05)
    yaw = np.unwrap(np.radians(rpy[:, 2]))
    yaw_rate = np.degrees(np.diff(yaw) / np.diff(t))
    assert 25.0 < yaw_rate.max() < 31.0 and yaw_rate.min() > -1.0
    assert np.degrees(yaw[-1] - yaw[0]) == pytest.approx(90.0, abs=0.5)
    assert rpy[:, 1].max() > 1.0   # nose down while braking to 4 m/s
    assert rpy[:, 0].max() > 0.7   # body rolls out of the left turn (right side down)


def test_departures_move_the_returns_as_their_physics_says(tmp_path):
    """Every departure on at once against the same drive without them (the same draws, so the same returns):
    the distance reads long by d x scale + bias (1 - cos incidence), the encoder lags the head by
    A sin(psi + phase), every return is stamped with its revolution's start plus the latency, the INS yaw
    drifts linearly; truth/effects.yaml lists each under its contract name with its magnitude."""
    departures = Departures(range_scale=0.0015, incidence_range_bias_m=0.04, eccentricity_deg=0.06,
                            eccentricity_phase_deg=30.0, latency_s=0.008, heading_drift_deg_s=0.02,
                            revolution_stamps=True)
    a = simulate("box_street", tmp_path / "a", duration_s=3.0, size=0.02, seed=2)
    b = simulate("box_street", tmp_path / "b", duration_s=3.0, size=0.02, seed=2, departures=departures)
    pa, pb = (pq.read_table(d / "points.parquet").to_pydict() for d in (a, b))
    assert len(pa["time"]) == len(pb["time"]) > 30_000
    fibre = np.asarray(pa["fibre"])
    _, offsets = read_csv(a / "truth" / "intrinsics.csv")
    distance = np.asarray(pa["range"], dtype=np.float64) + offsets[fibre, 1]
    bias = np.asarray(pb["range"], dtype=np.float64) - np.asarray(pa["range"], dtype=np.float64) - 0.0015 * distance
    assert bias.min() > -3e-5 and bias.max() < 0.04 + 3e-5 and bias.max() > 0.03  # grazing road returns
    azimuth = np.asarray(pa["azimuth"], dtype=np.float64)
    lag = np.angle(np.exp(1j * (np.asarray(pb["azimuth"], dtype=np.float64) - azimuth)))
    np.testing.assert_allclose(lag, -np.radians(0.06) * np.sin(azimuth + np.radians(30.0)), atol=3e-6)
    into_revolution = np.asarray(pa["time"]) + 0.008 - np.asarray(pb["time"])
    np.testing.assert_allclose(into_revolution, azimuth / (2 * np.pi * 10.0), atol=2e-4)
    scan = np.asarray(pb["scan"])
    assert all(len(np.unique(np.asarray(pb["time"])[scan == k])) == 1 for k in np.unique(scan))
    (_, ins_a), (_, ins_b) = read_csv(a / "trajectory.csv"), read_csv(b / "trajectory.csv")
    np.testing.assert_allclose(ins_b[:, :6], ins_a[:, :6])
    drift = np.angle(np.exp(1j * np.radians(ins_b[:, 6] - ins_a[:, 6])))
    np.testing.assert_allclose(np.degrees(drift), 0.02 * (ins_a[:, 0] - ins_a[0, 0]), atol=1e-7)
    effects = yaml.safe_load((b / "truth" / "effects.yaml").read_text())
    assert {name: effects[name]["magnitude"] for name in ("intra_sweep_motion", "range_scale", "incidence_range_bias",
                                                          "azimuth_eccentricity", "time_offset", "heading_drift")} == {
        "intra_sweep_motion": 1.0, "range_scale": 0.0015, "incidence_range_bias": 0.04,
        "azimuth_eccentricity": 0.06, "time_offset": 0.008, "heading_drift": 0.02}
