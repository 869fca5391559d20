"""SBET and CSV trajectory importers: attitude conversion against independent matrix math,
known poses, bad files, and the real SBET sample."""

from pathlib import Path

import numpy as np
import pytest

from graphcal.common.errors import ConfigError, RecordingError
from graphcal.importers.sbet import FIELDS, import_sbet, ned_to_enu_attitude_deg
from graphcal.importers.trajectory_csv import CsvTrajectoryFormat, import_trajectory_csv
from graphcal.recording.rotations import rotation_from_rpy_deg

SBET = Path(__file__).resolve().parents[2] / "shared/data/real/leeward_airborne_las_sbet/sbet.out"


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


ENU_FROM_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
FRD_FROM_FLU = np.diag([1.0, -1.0, -1.0])


def test_ned_attitude_conversion_matches_the_frame_matrices():
    """R_enu_flu = R_enu_ned R_ned_frd R_frd_flu with R_ned_frd = Rz(heading) Ry(pitch) Rx(roll)."""
    rng = np.random.default_rng(0)
    roll, pitch, heading = rng.uniform(-0.6, 0.6, 50), rng.uniform(-0.6, 0.6, 50), rng.uniform(-np.pi, np.pi, 50)
    rpy = ned_to_enu_attitude_deg(roll, pitch, heading)
    for k in range(50):
        expected = ENU_FROM_NED @ _rz(heading[k]) @ _ry(pitch[k]) @ _rx(roll[k]) @ FRD_FROM_FLU
        np.testing.assert_allclose(rotation_from_rpy_deg(rpy[k]).as_matrix(), expected, atol=1e-12)


def test_known_poses():
    # heading 90 deg (facing east), nose up 10 deg (NED pitch > 0), right wing down 5 deg (roll > 0)
    rpy = ned_to_enu_attitude_deg(np.radians([5.0]), np.radians([10.0]), np.radians([90.0]))[0]
    rotation = rotation_from_rpy_deg(rpy)
    forward, left = rotation.apply([1.0, 0.0, 0.0]), rotation.apply([0.0, 1.0, 0.0])
    np.testing.assert_allclose(forward, [np.cos(np.radians(10)), 0.0, np.sin(np.radians(10))], atol=1e-12)
    assert left[1] > 0.99 and left[2] == pytest.approx(np.cos(np.radians(10)) * np.sin(np.radians(5)), abs=1e-12)
    assert ned_to_enu_attitude_deg(np.zeros(1), np.zeros(1), np.zeros(1))[0, 2] == 90.0  # north = 90 deg from east


def _sbet_records(n=5):
    records = np.zeros((n, 17))
    records[:, 0] = 345600.0 + 0.005 * np.arange(n)
    records[:, 1], records[:, 2], records[:, 3] = np.radians(48.5), np.radians(2.25), 120.0
    records[:, 7], records[:, 8] = np.radians(1.0), np.radians(-2.0)
    records[:, 9] = np.radians([350.0, 355.0, 0.0, 5.0, 10.0][:n])  # crosses north: yaw must not jump
    return records


def test_sbet_records_become_a_geodetic_trajectory(tmp_path):
    path = tmp_path / "sbet.out"
    _sbet_records().astype("<f8").tofile(path)
    trajectory = import_sbet(path)
    assert trajectory.geodetic and len(FIELDS) == 17
    np.testing.assert_allclose(trajectory.time, 345600.0 + 0.005 * np.arange(5))
    np.testing.assert_allclose(trajectory.position, [[48.5, 2.25, 120.0]] * 5)
    np.testing.assert_allclose(trajectory.rpy_deg[:, :2], [[1.0, 2.0]] * 5)
    np.testing.assert_allclose(trajectory.rpy_deg[:, 2], [100.0, 95.0, 90.0, 85.0, 80.0])
    cropped = import_sbet(path, time_range=(345600.006, 345600.009))
    np.testing.assert_allclose(cropped.time, [345600.005, 345600.010])


def test_bad_sbet_files(tmp_path):
    path = tmp_path / "cut.out"
    path.write_bytes(_sbet_records().astype("<f8").tobytes()[:-8])
    with pytest.raises(RecordingError, match=r"cut\.out: 672 bytes: record 4 has 128 of its 136 bytes"):
        import_sbet(path)
    records = _sbet_records()
    records[3, 0] = records[2, 0]
    path = tmp_path / "time.out"
    records.astype("<f8").tofile(path)
    with pytest.raises(RecordingError, match="field 'time', row 3"):
        import_sbet(path)
    records = _sbet_records()
    records[1, 1] = 48.5  # degrees
    path = tmp_path / "deg.out"
    records.astype("<f8").tofile(path)
    with pytest.raises(RecordingError, match="field 'lat', row 1"):
        import_sbet(path)


@pytest.mark.skipif(not SBET.is_file(), reason="shared real data absent")
def test_real_sbet():
    """leeward's sbet.out (SOURCE.md: 200 records, 1 s at 200 Hz, about 6990 m altitude)."""
    trajectory = import_sbet(SBET)
    assert len(trajectory.time) == 200
    np.testing.assert_allclose(np.diff(trajectory.time), 0.005, atol=1e-4)
    assert 6980 < trajectory.position[:, 2].mean() < 7000
    raw = np.fromfile(SBET, dtype="<f8").reshape(-1, 17)
    turn = np.mod(trajectory.rpy_deg[:, 2] - (90.0 - np.degrees(raw[:, 9])) + 180.0, 360.0) - 180.0
    np.testing.assert_allclose(turn, 0.0, atol=1e-9)
    np.testing.assert_allclose(trajectory.position[:, 0], np.degrees(raw[:, 1]))
    assert 0.0 <= trajectory.time[0] < 604800.0


def test_csv_with_named_columns_radians_and_ned_attitude(tmp_path):
    records = _sbet_records()
    path = tmp_path / "ins.csv"
    rows = ["gps_s;latitude;longitude;h;r;p;hdg"] + [";".join(f"{v:.12f}" for v in rec[[0, 1, 2, 3, 7, 8, 9]])
                                                    for rec in records]
    path.write_text("\n".join(rows) + "\n")
    fmt = CsvTrajectoryFormat(columns={"time": "gps_s", "lat": "latitude", "lon": "longitude", "alt": "h",
                                       "roll": "r", "pitch": "p", "heading": "hdg"},
                              attitude="ned", radians=True, delimiter=";")
    trajectory = import_trajectory_csv(path, fmt)
    sbet_path = tmp_path / "same.out"
    records.astype("<f8").tofile(sbet_path)
    reference = import_sbet(sbet_path)
    np.testing.assert_allclose(trajectory.position, reference.position, atol=1e-9)
    np.testing.assert_allclose(trajectory.rpy_deg, reference.rpy_deg, atol=1e-9)


def test_projected_csv_and_bad_rows(tmp_path):
    path = tmp_path / "grid.csv"
    path.write_text("t,x,y,z,roll,pitch,yaw,extra\n10,500000,5400000,100,0,0,170,a\n11,500001,5400000,100,0,0,-170,b\n")
    trajectory = import_trajectory_csv(path, CsvTrajectoryFormat(position="projected", time_offset_s=100.0,
                                                                 columns={"time": "t"}))
    assert not trajectory.geodetic
    np.testing.assert_allclose(trajectory.time, [110.0, 111.0])
    np.testing.assert_allclose(trajectory.rpy_deg[:, 2], [170.0, 190.0])  # unwrapped
    path.write_text("t,x,y,z,roll,pitch,yaw\n10,500000,5400000,100,0,0,0\n11,500001,oops,100,0,0,0\n")
    with pytest.raises(RecordingError, match=r"grid\.csv, field 'y', row 2: value 'oops'"):
        import_trajectory_csv(path, CsvTrajectoryFormat(position="projected", columns={"time": "t"}))
    with pytest.raises(RecordingError, match="no column 'lat'"):
        import_trajectory_csv(path, CsvTrajectoryFormat(columns={"time": "t"}))
    path.write_text("time,lat,lon,alt,roll,pitch,yaw\n1,45,6,0,0,0,0\n1,45,6,0,0,0,0\n")
    with pytest.raises(RecordingError, match="field 'time', row 2"):
        import_trajectory_csv(path)
    with pytest.raises(ConfigError, match="unknown trajectory field 'speed'"):
        CsvTrajectoryFormat(columns={"speed": "v"})
