"""`graphcal import pcap|kitti|sbet|csv`: files written, notes printed, bad input in one line."""

from pathlib import Path

import numpy as np
from test_importers_kitti import _unit_hdl64e, _write_drive
from test_importers_trajectory import _sbet_records
from typer.testing import CliRunner
from velodyne_synth import position_packet, spinning_capture, udp_frame

from graphcal.cli.main import app
from graphcal.importers.sbet import import_sbet
from graphcal.recording.directory import Recording
from graphcal.recording.trajectory import Trajectory


def _capture_with_fix(tmp_path):
    sentence = "$GPRMC,101705,A,4851.3000,N,00221.0000,E,000.0,000.0,040321,,,A"
    fix = (1614853025.0, udp_frame(position_packet(int(1026.2e6), sentence), 8308))
    path = tmp_path / "drive.pcap"
    path.write_bytes(spinning_capture(n_packets=20, packet_us=552.96, block_step=19.9, start_us=int(1026.2e6),
                                      extra=[fix]).pcap)
    return path


def test_import_pcap_with_an_sbet_and_an_extrinsic(tmp_path):
    pcap = _capture_with_fix(tmp_path)
    runner = CliRunner()
    result = runner.invoke(app, ["import", "pcap", str(pcap), "--out", str(tmp_path / "static")])
    assert result.exit_code == 0, result.output
    assert "STATIC trajectory" in result.output and "GPS seconds of week 2147" in result.output
    static = Recording.load(tmp_path / "static")
    start, end = static.trajectory.time[0], static.trajectory.time[-1]
    records = _sbet_records(5)
    records[:, 0] = np.linspace(start - 1.0, end + 1.0, 5)
    sbet = tmp_path / "nav.out"
    records.astype("<f8").tofile(sbet)
    result = runner.invoke(app, ["import", "pcap", str(pcap), "--out", str(tmp_path / "moving"), "--trajectory",
                                 str(sbet), "--lever-arm", "0.8,0,1.9", "--boresight", "0,0,90", "-q"])
    assert result.exit_code == 0 and result.output.strip() == ""
    moving = Recording.load(tmp_path / "moving")
    assert moving.extrinsic.lever_arm_m == (0.8, 0.0, 1.9) and moving.extrinsic.boresight_deg == (0.0, 0.0, 90.0)
    np.testing.assert_allclose(moving.trajectory.time, records[:, 0], atol=1e-6)
    assert len(moving.points) == len(static.points)


def test_import_pcap_bad_input_is_one_line(tmp_path):
    pcap = _capture_with_fix(tmp_path)
    cut = tmp_path / "cut.pcap"
    cut.write_bytes(pcap.read_bytes()[:-50])
    runner = CliRunner()
    result = runner.invoke(app, ["import", "pcap", str(cut), "--out", str(tmp_path / "cut")])
    assert result.exit_code == 0 and "cut short" in result.output, result.output  # the whole records are kept
    (tmp_path / "empty.pcap").write_bytes(b"")
    for arguments, words in ((["import", "pcap", str(tmp_path / "empty.pcap")], "empty.pcap: empty file (expected"),
                             (["import", "pcap", str(pcap), "--position", "45,6"], "--position: '45,6' is not 3"),
                             (["import", "pcap", str(pcap), "--position", "nan,nan,nan"], "finite numbers"),
                             (["import", "pcap", str(pcap), "--attitude", "inf,0,0"], "--attitude: 'inf,0,0'"),
                             (["import", "pcap", str(pcap), "--model", "VLP-32"], "unknown Velodyne model")):
        result = runner.invoke(app, arguments)
        assert result.exit_code == 2, result.output
        lines = result.output.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("error: ") and words in lines[0]
    result = runner.invoke(app, ["import", "pcap", str(pcap), "--position", "100,0,0", "--out", str(tmp_path / "lat")])
    assert result.exit_code == 2 and "--position: '100,0,0': latitude within +-90 deg" in result.output, result.output
    assert not (tmp_path / "lat").exists()  # refused before anything is written
    (tmp_path / "taken").mkdir()
    (tmp_path / "taken" / "recording.yaml").write_text("format: graphcal-recording/1\n")
    result = runner.invoke(app, ["import", "pcap", str(pcap), "--out", str(tmp_path / "taken")])
    assert result.exit_code == 2 and "taken: already exists; an import does not replace it" in result.output
    assert (tmp_path / "taken" / "recording.yaml").read_text() == "format: graphcal-recording/1\n"


def test_import_sbet_and_csv_write_trajectory_csv(tmp_path):
    sbet = tmp_path / "nav.out"
    _sbet_records().astype("<f8").tofile(sbet)
    runner = CliRunner()
    result = runner.invoke(app, ["import", "sbet", str(sbet), "--out", str(tmp_path / "sbet.csv"), "--start",
                                 "345600.004", "--end", "345600.011"])
    assert result.exit_code == 0, result.output
    written = Trajectory.load_csv(tmp_path / "sbet.csv")
    reference = import_sbet(sbet)
    np.testing.assert_allclose(written.time, reference.time[:4])
    np.testing.assert_allclose(written.rpy_deg, reference.rpy_deg[:4], atol=1e-6)
    source = tmp_path / "ins.csv"
    source.write_text("t;la;lo;h;r;p;hd\n" + "\n".join(f"{10 + k};48.5;2.25;120;1;-2;{350 + 5 * k}" for k in range(3)))
    result = runner.invoke(app, ["import", "csv", str(source), "--out", str(tmp_path / "t.csv"), "--delimiter", ";",
                                 "--attitude", "ned", "--columns", "time=t,lat=la,lon=lo,alt=h,roll=r,pitch=p,heading=hd"])
    assert result.exit_code == 0, result.output
    np.testing.assert_allclose(Trajectory.load_csv(tmp_path / "t.csv").rpy_deg, [[1, 2, 100], [1, 2, 95], [1, 2, 90]])
    result = runner.invoke(app, ["import", "csv", str(source), "--columns", "time"])
    assert result.exit_code == 2 and "not FIELD=COLUMN" in result.output
    before = (tmp_path / "t.csv").read_bytes()
    for command in (["sbet", str(sbet)], ["csv", str(source), "--delimiter", ";"]):  # an import replaces nothing
        result = runner.invoke(app, ["import", *command, "--out", str(tmp_path / "t.csv")])
        assert result.exit_code == 2 and "already exists" in result.output, result.output
    assert (tmp_path / "t.csv").read_bytes() == before


def test_import_kitti(tmp_path):
    drive, truth = _write_drive(tmp_path, _unit_hdl64e(), n_scans=2, columns=40)
    result = CliRunner().invoke(app, ["import", "kitti", str(drive), "--out", str(tmp_path / "kitti")])
    assert result.exit_code == 0, result.output
    assert "DERIVED from the azimuth" in result.output
    assert len(Recording.load(tmp_path / "kitti").points) == len(truth["time"])


def test_import_of_a_folder_that_is_no_bag_is_one_line(tmp_path):
    (tmp_path / "photos").mkdir()
    (tmp_path / "photos" / "a.txt").write_text("not a bag")
    result = CliRunner().invoke(app, ["import", "pcap", str(tmp_path / "photos"), "--out", str(tmp_path / "rec")])
    assert result.exit_code == 2 and result.output.count("\n") == 1, result.output
    assert "photos: a folder without metadata.yaml: not a rosbag2 recording" in result.output
    assert not (tmp_path / "rec").exists()
    result = CliRunner().invoke(app, ["import", "pointcloud2", str(tmp_path / "photos"), "--out", str(tmp_path / "rec")])
    assert result.exit_code == 2 and "a folder without metadata.yaml" in result.output, result.output


def test_an_import_refused_after_it_began_to_write_leaves_nothing(tmp_path, monkeypatch):
    """A recording folder an import had begun to write is removed when the import is then refused; a folder that was
    there, empty, before is not removed."""
    from graphcal.common.errors import RecordingError

    def refused(source, trajectory, out, **options):
        Path(out).mkdir(parents=True, exist_ok=True)
        (Path(out) / "points.parquet").write_bytes(b"half")
        raise RecordingError(source, "refused after writing began")

    monkeypatch.setattr("graphcal.importers.las_cloud.import_las", refused)
    (tmp_path / "sbet.csv").write_text("time,lat,lon,alt,roll,pitch,yaw\n0,45,6,300,0,0,0\n1,45,6,300,0,0,0\n")
    (tmp_path / "empty").mkdir()
    for out, kept in ((tmp_path / "new", False), (tmp_path / "empty", True)):
        result = CliRunner().invoke(app, ["import", "las", str(tmp_path / "x.las"), "--trajectory",
                                          str(tmp_path / "sbet.csv"), "--out", str(out)])
        assert result.exit_code == 2 and "refused after writing began" in result.output, result.output
        assert out.exists() == kept
