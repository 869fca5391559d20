"""KITTI raw importer on a small drive the test writes from a known ground truth (no real KITTI
sample is available): raw values, derived times, fibres, OXTS trajectory, extrinsic."""

import calendar
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from graphcal.common.errors import RecordingError
from graphcal.importers.kitti import import_kitti
from graphcal.recording.directory import Recording
from graphcal.recording.sensor import sensor_from_catalog

START = calendar.timegm((2011, 9, 26, 13, 2, 25)) + 0.5  # UTC
SCAN_S = 0.1035


def _stamp(utc_s: float) -> str:
    whole = int(np.floor(utc_s))
    return f"{time.strftime('%Y-%m-%d %H:%M:%S', time.gmtime(whole))}.{round((utc_s - whole) * 1e9):09d}"


def _write_drive(root, sensor, n_scans=3, columns=300, seed=0, oxts_start_delay=0.0):
    """A KITTI-like drive from `sensor` (eq. 4.2 + factory terms; the points are what the driver
    would output). Returns the drive folder and the true raw values of every written point."""
    rng = np.random.default_rng(seed)
    drive = root / "2011_09_26" / "2011_09_26_drive_0001_sync"
    (drive / "velodyne_points" / "data").mkdir(parents=True)
    (drive / "oxts" / "data").mkdir(parents=True)
    truth = {key: [] for key in ("time", "fibre", "range", "azimuth", "xyz", "intensity", "norm")}
    starts = START + SCAN_S * np.arange(n_scans)
    for k, start in enumerate(starts):
        theta = np.mod(np.pi + 2 * np.pi * (np.arange(columns) + rng.uniform(0, 1, columns)) / columns, 2 * np.pi)
        fibre = np.repeat(np.arange(sensor.n_fibres)[None, :], columns, axis=0).ravel()
        azimuth = np.repeat(theta, sensor.n_fibres)
        range_m = rng.uniform(3.0, 60.0, fibre.size)
        xyz = sensor.to_xyz(fibre, range_m, azimuth)
        order = rng.permutation(fibre.size)
        scan = np.column_stack([xyz, rng.uniform(0, 1, fibre.size)])[order].astype("<f4")
        scan = np.vstack([scan, np.zeros((2, 4), dtype="<f4")])  # two empty points, as KITTI has
        scan.tofile(drive / "velodyne_points" / "data" / f"{k:010d}.bin")
        truth["time"].append(start + SCAN_S * np.mod(azimuth - np.pi, 2 * np.pi)[order] / (2 * np.pi))
        truth["fibre"].append(fibre[order])
        truth["range"].append(range_m[order])
        truth["azimuth"].append(azimuth[order])
        truth["xyz"].append(xyz[order])
        truth["intensity"].append(scan[:-2, 3] * 255.0)  # what the importer stores: keys to match rows
        truth["norm"].append(np.linalg.norm(scan[:-2, :3].astype(np.float64), axis=1))
    for name, stamps in (("timestamps_start.txt", starts), ("timestamps_end.txt", starts + SCAN_S),
                         ("timestamps.txt", starts + SCAN_S / 2)):
        (drive / "velodyne_points" / name).write_text("\n".join(_stamp(t) for t in stamps) + "\n")
    oxts_times = START + oxts_start_delay + 0.1 * np.arange(5)
    for k, _ in enumerate(oxts_times):
        fields = [49.0 + 1e-5 * k, 8.4, 115.0, 0.01, -0.02, 0.3 + 0.01 * k] + [0.0] * 24
        (drive / "oxts" / "data" / f"{k:010d}.txt").write_text(" ".join(f"{v:.12g}" for v in fields) + "\n")
    (drive / "oxts" / "timestamps.txt").write_text("\n".join(_stamp(t) for t in oxts_times) + "\n")
    rotation = Rotation.from_euler("z", 1.0, degrees=True).as_matrix()
    (drive.parent / "calib_imu_to_velo.txt").write_text(
        "calib_time: 25-May-2012 16:47:16\nR: " + " ".join(f"{v:.9e}" for v in rotation.ravel())
        + "\nT: 8.1e-01 -3.2e-01 8.0e-01\n")
    return drive, {key: np.concatenate(values) for key, values in truth.items()}


def _gps_seconds_of_week(utc_s):
    """UTC s since 1970 (on 2011-09-26) -> GPS seconds of week, GPS - UTC = 15 s in 2011."""
    midnight = calendar.timegm((2011, 9, 26, 0, 0, 0))
    gps_day = midnight - calendar.timegm((1980, 1, 6, 0, 0, 0)) + 15
    week = gps_day // 604800
    return utc_s - midnight + gps_day - week * 604800, week


def _matched(columns, norm="range"):
    """Rows ordered by intensity then |p| (random float32 values written into the file): the
    importer sorts by derived time, whose ties (one firing column) float32 noise breaks at random."""
    order = np.lexsort((np.float32(columns[norm]), np.float32(columns["intensity"])))
    return {key: values[order] for key, values in columns.items()}


def _unit_hdl64e(seed=1):
    """An HDL-64E unit: elevations 0.05 deg and vertical offsets 1 cm (rms) off the catalogue's, no
    azimuth or horizontal offsets (KITTI's points cannot show those)."""
    sensor = sensor_from_catalog("HDL-64E")
    rng = np.random.default_rng(seed)
    return type(sensor)(**{**sensor.__dict__, "elevation_deg": sensor.elevation_deg + rng.normal(0, 0.05, 64),
                           "vertical_offset_m": sensor.vertical_offset_m + rng.normal(0, 0.01, 64),
                           "azimuth_offset_deg": np.zeros(64), "horizontal_offset_m": np.zeros(64)})


def test_kitti_drive_raw_values_times_and_poses(tmp_path):
    unit = _unit_hdl64e()
    drive, truth = _write_drive(tmp_path, unit)
    import_kitti(drive, tmp_path / "rec", quiet=True)
    loaded = Recording.load(tmp_path / "rec")
    truth["time"], week = _gps_seconds_of_week(truth["time"])
    stored = loaded.points.read()
    stored, truth = _matched(stored), _matched(truth, "norm")
    right = stored["fibre"] == truth["fibre"]
    # beam lines of neighbouring fibres cross within a few metres of the head (vertical offsets differ)
    assert right.mean() > 0.999 and np.all(truth["range"][~right] < 10.0)
    np.testing.assert_allclose(stored["range"][right], truth["range"][right], atol=5e-5)  # fitted model
    np.testing.assert_allclose(np.angle(np.exp(1j * (stored["azimuth"] - truth["azimuth"]))), 0.0, atol=2e-6)
    np.testing.assert_allclose(stored["time"], truth["time"], rtol=0, atol=1e-6)
    assert loaded.source["gps_week"] == week
    np.testing.assert_allclose(loaded.sensor.elevation_deg, unit.elevation_deg, atol=1e-4)
    np.testing.assert_allclose(loaded.sensor.vertical_offset_m, unit.vertical_offset_m, atol=1e-5)
    np.testing.assert_allclose(loaded.sensor.to_xyz(stored["fibre"].astype(int), stored["range"].astype(float),
                                                    stored["azimuth"].astype(float)), truth["xyz"], atol=1e-4)
    assert loaded.sensor.rotation_hz == pytest.approx(1 / SCAN_S, rel=1e-5)  # timestamps in ns
    np.testing.assert_allclose(loaded.trajectory.rpy_deg[:, 2], np.degrees(0.3 + 0.01 * np.arange(5)), atol=1e-6)
    np.testing.assert_allclose(loaded.trajectory.position[0], [49.0, 8.4, 115.0])
    # extrinsic: p_velo = R p_imu + T inverted
    p_imu = np.array([[1.0, 2.0, 3.0]])
    p_velo = p_imu @ Rotation.from_euler("z", 1.0, degrees=True).as_matrix().T + [0.81, -0.32, 0.80]
    np.testing.assert_allclose(loaded.extrinsic.lidar_to_body(p_velo), p_imu, atol=1e-9)
    assert any("DERIVED from the azimuth" in note for note in loaded.source["notes"])


def test_returns_before_the_first_oxts_pose_are_left_out(tmp_path):
    drive, truth = _write_drive(tmp_path, _unit_hdl64e(), n_scans=2, columns=50, oxts_start_delay=0.02)
    recording = import_kitti(drive, tmp_path / "rec", quiet=True)
    dropped = int((truth["time"] < START + 0.02).sum())
    assert len(recording.points) == len(truth["time"]) - dropped > 0
    assert any(f"{dropped} returns outside the OXTS time span" in note for note in recording.source["notes"])


def test_kitti_with_azimuth_and_horizontal_offsets(tmp_path):
    """Points corrected with all the catalogue's HDL-64E factory terms (vertical offsets 0.14-0.20 m,
    horizontal offsets 2.6 cm, azimuth offsets 4 deg): the fitted model still gives back every
    point (the azimuth and horizontal offsets only turn the point about the spin axis), but the
    encoder azimuth, and so the derived time, is off by the azimuth offset: 4 deg of a 0.1035 s
    turn = 1.15 ms; a return within 4 deg of the scan's start/end azimuth lands at the other end, a scan off."""
    sensor = sensor_from_catalog("HDL-64E")
    drive, truth = _write_drive(tmp_path, sensor, n_scans=1, columns=200)
    recording = import_kitti(drive, tmp_path / "rec", quiet=True)
    stored, truth = _matched(recording.points.read()), _matched(truth, "norm")
    assert np.mean(stored["fibre"] == truth["fibre"]) > 0.999
    xyz = recording.sensor.to_xyz(stored["fibre"].astype(int), stored["range"].astype(float),
                                  stored["azimuth"].astype(float))
    assert np.linalg.norm(xyz - truth["xyz"], axis=1).max() < 1e-4
    note = next(n for n in recording.source["notes"] if "misfit" in n)
    assert "median 0.0 mm" in note
    time_error = np.abs(stored["time"] - _gps_seconds_of_week(truth["time"])[0])
    near = time_error < 1.5e-3  # 4 deg, and atan(2.6 cm / range) for the horizontal offset
    assert near.mean() > 0.95 and np.all(near | (np.abs(time_error - SCAN_S) < 1.5e-3))


def test_import_streams_scan_by_scan_and_writes_what_the_whole_drive_gives(tmp_path):
    """One scan read and written at a time (the returns of a scan in random order, the time-sorted writer merging
    them with the next scan's), the recording is the one of all the scans written at once, byte for byte; its
    returns are the drive's, sorted by time, those before the first OXTS pose left out."""
    drive, truth = _write_drive(tmp_path, _unit_hdl64e(), n_scans=4, columns=60, oxts_start_delay=0.03)
    streamed = import_kitti(drive, tmp_path / "streamed", chunk_scans=1, quiet=True)
    whole = import_kitti(drive, tmp_path / "whole", chunk_scans=1000, quiet=True)
    files = sorted(path.name for path in (tmp_path / "whole").iterdir())
    assert files == sorted(path.name for path in (tmp_path / "streamed").iterdir()) and "points.parquet" in files
    for name in files:
        assert (tmp_path / "whole" / name).read_bytes() == (tmp_path / "streamed" / name).read_bytes(), name
    returns = streamed.points.read()
    kept = truth["time"] >= START + 0.03
    assert len(returns["time"]) == kept.sum() == whole.points.read()["time"].size > 0
    assert np.all(np.diff(returns["time"]) >= 0)
    np.testing.assert_array_equal(np.bincount(returns["scan"]), np.bincount(np.repeat(np.arange(4), 60 * 64)[kept]))
    np.testing.assert_allclose(np.sort(returns["time"]), np.sort(_gps_seconds_of_week(truth["time"][kept])[0]),
                               rtol=0, atol=1e-6)
    assert any(f"{int((~kept).sum())} returns outside the OXTS time span" in note for note in streamed.source["notes"])


def test_a_drive_whose_scans_go_back_in_time_is_refused(tmp_path):
    """The last scan stamped before the first (two scans and more out of order: the writer holds back one
    scan's returns only): the scan-by-scan import names the time field and the order it expects, and writes
    nothing."""
    drive, _ = _write_drive(tmp_path, _unit_hdl64e(), n_scans=4, columns=20)
    for name in ("timestamps_start.txt", "timestamps_end.txt"):
        path = drive / "velodyne_points" / name
        lines = path.read_text().splitlines()
        path.write_text("\n".join(lines[1:] + lines[:1]) + "\n")
    with pytest.raises(RecordingError, match="time.*scans in time order"):
        import_kitti(drive, tmp_path / "rec", quiet=True)
    assert not (tmp_path / "rec").exists()


def test_bad_kitti_drive(tmp_path):
    with pytest.raises(RecordingError, match="no .bin scans"):
        import_kitti(tmp_path, tmp_path / "rec", quiet=True)
    drive, _ = _write_drive(tmp_path, sensor_from_catalog("HDL-64E"), n_scans=2, columns=10)
    (drive / "velodyne_points" / "timestamps_end.txt").write_text(_stamp(START) + "\n")
    with pytest.raises(RecordingError, match="1 timestamps for 2 scans"):
        import_kitti(drive, tmp_path / "rec", quiet=True)
    (drive / "velodyne_points" / "timestamps_end.txt").write_text("yesterday\nnoon\n")
    with pytest.raises(RecordingError, match=r"timestamps_end\.txt, row 1: timestamp 'yesterday'"):
        import_kitti(drive, tmp_path / "rec", quiet=True)
