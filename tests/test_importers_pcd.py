"""PCD reader (ascii, binary, binary_compressed) and `import pcd` on synthetic scans written here from known raw
returns, on the OpenCalib sample (5 real binary_compressed scans with ring and time, poses) and on nebula's decoded
VLP-16 scan (its own range and azimuth per point)."""

from pathlib import Path

import pylzf
import numpy as np
import pytest
from typer.testing import CliRunner

from graphcal.cli.main import app
from graphcal.common.errors import RecordingError
from graphcal.importers.beam_fit import ring_model
from graphcal.importers.frame_poses import read_frame_poses
from graphcal.importers.pcd import read_pcd
from graphcal.importers.pcd_folder import import_pcd_folder
from graphcal.importers.point_fields import scan_points
from graphcal.importers.velodyne_calibration import read_velodyne_calibration
from graphcal.recording.directory import Recording
import ring_scans_synth as synth

REAL = Path("/work/shared/data/real")
PJLAB = REAL / "pjlab_lidar2imu_pcd_poses"
NEBULA = REAL / "nebula_velodyne_rosbag2"
_TYPES = {"f": "F", "u": "U", "i": "I"}


def write_pcd(path: Path, points: np.ndarray, encoding: str) -> None:
    """A PCD v0.7 file of a structured array (sub-array fields as COUNT > 1), as PCL writes it."""
    names = points.dtype.names
    columns = [points.dtype[n] for n in names]
    header = ["# .PCD v0.7 - Point Cloud Data file format", "VERSION 0.7", "FIELDS " + " ".join(names),
              "SIZE " + " ".join(str(c.base.itemsize) for c in columns),
              "TYPE " + " ".join(_TYPES[c.base.kind] for c in columns),
              "COUNT " + " ".join(str(int(np.prod(c.shape or (1,)))) for c in columns),
              f"WIDTH {len(points)}", "HEIGHT 1", "VIEWPOINT 0 0 0 1 0 0 0", f"POINTS {len(points)}",
              f"DATA {encoding}"]
    head = ("\n".join(header) + "\n").encode()
    if encoding == "ascii":
        flat = np.column_stack([points[n].reshape(len(points), -1).astype(np.float64) for n in names])
        body = "".join(" ".join(f"{v:.17g}" for v in row) + "\n" for row in flat).encode()
    elif encoding == "binary":
        body = points.astype(points.dtype.newbyteorder("<")).tobytes()
    else:
        raw = b"".join(np.ascontiguousarray(points[n]).astype(points.dtype[n].base.newbyteorder("<")).tobytes()
                       for n in names)
        packed = pylzf.compress(raw)
        body = np.array([len(packed), len(raw)], dtype="<u4").tobytes() + packed
    path.write_bytes(head + body)


def _scan_array(scan: dict, time_field: str, relative: bool) -> np.ndarray:
    kinds = {"t": "<u4", "time": "<f4", "timestamp": "<f8"}
    dtype = [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4"), ("ring", "<u2"),
             (time_field, kinds[time_field])]
    points = np.zeros(len(scan["time"]), dtype=dtype)
    points["x"], points["y"], points["z"] = scan["xyz"].T
    points["intensity"], points["ring"] = scan["intensity"], scan["ring"]
    offset = scan["time"] - scan["stamp"] if relative else scan["time"]
    points[time_field] = np.round(offset * 1e9) if time_field == "t" else offset
    return points


def _truth(scans: list[dict]) -> dict:
    return {key: np.concatenate([s[key] for s in scans]) for key in ("time", "fibre", "ring", "range", "azimuth")}


def _matched(recording: Recording, truth: dict, model) -> tuple[dict, dict]:
    """The recording's returns and the true ones, matched by time (each return has its own time)."""
    points = recording.points.read()
    from graphcal.importers.gpstime import seconds_of_week

    base = np.floor(truth["time"].min())
    true_time, _ = seconds_of_week(base, truth["time"] - base, recording.source["gps_week"])
    index = synth.nearest(true_time, points["time"])
    assert np.all(np.abs(true_time[index] - points["time"]) < 2e-6)
    return points, {key: values[index] for key, values in truth.items()}


def test_pcd_encodings_read_back_every_field(tmp_path):
    rng = np.random.default_rng(1)
    points = np.zeros(50, dtype=[("x", "<f4"), ("y", "<f8"), ("ring", "<u2"), ("t", "<u4"), ("n", "<i1"),
                                 ("normal", "<f4", (3,))])
    for name in points.dtype.names:
        shape = (50,) + points.dtype[name].shape
        points[name] = rng.integers(-100, 100, shape) if points.dtype[name].base.kind == "i" else rng.uniform(0, 9e3, shape)
    for encoding in ("ascii", "binary", "binary_compressed"):
        write_pcd(tmp_path / f"{encoding}.pcd", points, encoding)
        header, read = read_pcd(tmp_path / f"{encoding}.pcd")
        assert header.encoding == encoding and header.fields == points.dtype.names
        for name in points.dtype.names:
            np.testing.assert_array_equal(read[name], points[name])


@pytest.mark.parametrize("encoding", ["ascii", "binary", "binary_compressed"])
def test_import_pcd_recovers_raw_returns_without_calibration(tmp_path, encoding):
    """Nameless (KITTI) poses, relative ns times counted from the ns stamp in the file name; the fitted model
    recovers elevation, range, encoder azimuth and time of a head with elevations and vertical offsets only."""
    model = synth.sensor(with_offsets=False)
    scans = synth.scans(model, n_scans=3)
    folder = tmp_path / "scans"
    folder.mkdir()
    for scan in scans:
        write_pcd(folder / f"{round(scan['stamp'] * 1e9)}.pcd", _scan_array(scan, "t", relative=True), encoding)
    poses = synth.kitti_poses(len(scans))
    (tmp_path / "poses.txt").write_text("".join(" ".join(f"{v:.9f}" for v in p.ravel()) + "\n" for p in poses))
    recording = import_pcd_folder(folder, tmp_path / "poses.txt", tmp_path / "rec", quiet=True)
    points, truth = _matched(recording, _truth(scans), model)
    # poses at each scan's last return: of scan 0, only its last return is within the trajectory
    assert len(points["time"]) == sum(len(s["time"]) for s in scans[1:]) + 1
    ring = truth["ring"]
    np.testing.assert_array_equal(points["fibre"], ring)  # fibre = ring id when fitted
    np.testing.assert_allclose(recording.sensor.elevation_deg[ring], model.elevation_deg[truth["fibre"]], atol=2e-3)
    np.testing.assert_allclose(recording.sensor.vertical_offset_m[ring], model.vertical_offset_m[truth["fibre"]],
                               atol=2e-4)
    np.testing.assert_allclose(points["range"], truth["range"], atol=2e-4)
    np.testing.assert_allclose(np.angle(np.exp(1j * (points["azimuth"] - truth["azimuth"]))), 0.0, atol=2e-5)
    assert recording.trajectory.time.size == len(scans)
    np.testing.assert_allclose(recording.trajectory.position, poses[:, :, 3], atol=1e-6)
    assert any("FITTED" in note for note in recording.source["notes"])


def test_import_pcd_with_calibration_and_named_poses(tmp_path):
    """Named (OpenCalib) poses, absolute float64 s times, a calibration with azimuth, range and horizontal
    offsets: raw range and encoder azimuth come back through the file's model; poses of frames without a PCD
    file are timed by their names."""
    model = synth.sensor(with_offsets=True)
    scans = synth.scans(model, n_scans=2, seed=3)
    write_calibration = tmp_path / "calib.yaml"
    synth.write_ros_calibration(write_calibration, model)
    folder = tmp_path / "scans"
    folder.mkdir()
    lines = []
    poses = synth.kitti_poses(4)
    for k in range(4):
        end = synth.START_UTC + (k + 1) * synth.PERIOD_S - 0.5 * synth.PERIOD_S / 120 / 16 * 15  # last return
        name = f"{end + 3600:.6f}"  # the names run one hour off the points' clock
        if k < len(scans):
            write_pcd(folder / f"f{k}.pcd", _scan_array(scans[k], "timestamp", relative=False), "binary")
            name = f"f{k}"
        lines.append(name + " " + " ".join(f"{v:.9f}" for v in poses[k].ravel()))
    (tmp_path / "poses.txt").write_text("\n".join(lines) + "\n")
    calibration = read_velodyne_calibration(write_calibration)
    recording = import_pcd_folder(folder, tmp_path / "poses.txt", tmp_path / "rec", calibration=calibration,
                                  quiet=True)
    points, truth = _matched(recording, _truth(scans), model)
    np.testing.assert_array_equal(points["fibre"], truth["fibre"])
    np.testing.assert_allclose(points["range"], truth["range"], atol=2e-4)
    np.testing.assert_allclose(np.angle(np.exp(1j * (points["azimuth"] - truth["azimuth"]))), 0.0, atol=2e-5)
    np.testing.assert_allclose(recording.sensor.azimuth_offset_deg, model.azimuth_offset_deg)


def test_import_pcd_errors_name_the_file(tmp_path):
    model = synth.sensor(with_offsets=False)
    scan = synth.scans(model, n_scans=1)[0]
    folder = tmp_path / "scans"
    folder.mkdir()
    points = _scan_array(scan, "t", relative=True)
    write_pcd(folder / "a.pcd", points[["x", "y", "z", "t"]], "binary")
    (tmp_path / "poses.txt").write_text("1 0 0 0 0 1 0 0 0 0 1 0\n")
    with pytest.raises(RecordingError, match="a.pcd.*no ring field"):
        import_pcd_folder(folder, tmp_path / "poses.txt", tmp_path / "rec", quiet=True)
    write_pcd(folder / "a.pcd", points, "binary")  # relative times, and no stamp in the name
    with pytest.raises(RecordingError, match="a.pcd.*relative"):
        import_pcd_folder(folder, tmp_path / "poses.txt", tmp_path / "rec", quiet=True)
    damaged = tmp_path / "damaged.pcd"
    write_pcd(damaged, points, "binary_compressed")
    damaged.write_bytes(damaged.read_bytes()[:-100])
    with pytest.raises(RecordingError, match="damaged.pcd.*DATA"):
        read_pcd(damaged)


@pytest.mark.parametrize("pose, problem", [("0 " * 12, "not a rotation"), ("2 0 0 0 0 1 0 0 0 0 1 0", "entry of 2"),
                                           ("1 0 0 0 0 1 0 0 0 0 -1 0", "det R = -1"),
                                           ("1 0 0 1e300 0 1 0 0 0 0 1 0", "coordinate of 1e[+]300 m")])
def test_a_pose_that_is_not_a_rotation_and_translation_is_refused_by_line(tmp_path, pose, problem):
    poses = tmp_path / "poses.txt"
    poses.write_text("# frames\n1 0 0 0 0 1 0 0 0 0 1 0\n" + pose + "\n")
    with pytest.raises(RecordingError, match=f"poses.txt.*row 3.*{problem}"):
        read_frame_poses(poses)


@pytest.mark.skipif(not PJLAB.is_dir(), reason="OpenCalib sample not present")
def test_opencalib_sample_imports(tmp_path):
    """5 real Hesai-class scans (binary_compressed, ring 0-60, absolute timestamp), poses in a local ENU frame."""
    result = CliRunner().invoke(app, ["import", "pcd", str(PJLAB / "top_center_lidar"), "--poses",
                                      str(PJLAB / "top_center_lidar-enu.txt"), "--out", str(tmp_path / "rec"), "-q"])
    assert result.exit_code == 0, result.output
    recording = Recording.load(tmp_path / "rec")
    summary = recording.validate()
    assert recording.sensor.n_fibres == 61 and summary.n_points > 300_000
    assert 0.39 < summary.time_max - summary.time_min < 0.41  # scans 2-5: the first ends at the first pose
    misfit = next(n for n in recording.source["notes"] if n.startswith("model misfit"))
    assert "median 0.1 mm" in misfit
    assert any("-28800.000 s" in n or "-28799.999 s" in n for n in recording.source["notes"])  # names in UTC+8


@pytest.mark.skipif(not NEBULA.is_dir(), reason="nebula sample not present")
def test_nebula_vlp16_scan_raw_values_match_the_decoder():
    """nebula wrote each point's own distance and azimuth: the model's inverse gives them back."""
    _, points = read_pcd(NEBULA / "vlp16" / "1673400472138016708.pcd")
    scan = scan_points(points, "vlp16.pcd", 1673400472.138016708)
    model = ring_model(scan.xyz, scan.ring, "VLP-16", 10.0, "vlp16.pcd",
                       read_velodyne_calibration(NEBULA / "calibration" / "VLP16.yaml"))
    fibre, range_m, azimuth, _ = model.raw(scan.ring, scan.xyz)
    echo = points[np.any(np.column_stack([points[n] for n in "xyz"]) != 0, axis=1)]
    np.testing.assert_allclose(range_m, echo["distance"], atol=1e-5)
    np.testing.assert_allclose(np.angle(np.exp(1j * (azimuth - echo["azimuth"]))), 0.0, atol=1e-6)
    np.testing.assert_allclose(scan.time_s - 1673400472.138016708, echo["time_stamp"] * 1e-9, atol=5e-7)  # float64 at 1.7e9 s
