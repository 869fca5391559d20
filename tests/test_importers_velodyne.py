"""Velodyne pcap importer: synthetic captures with known raw values, velodyne-decoder as the
reference decoder, VeloView's expected frames and points on the real samples."""

import calendar
from pathlib import Path

import numpy as np
import pytest
import velodyne_decoder as vd
import yaml
from scipy.spatial import cKDTree
from velodyne_reference import decoder_minus_model, reference_xyz
from velodyne_synth import (
    data_packet,
    pcap_file,
    position_packet,
    spinning_capture,
    udp_frame,
)

from graphcal.common.errors import ConfigError, RecordingError
from graphcal.importers.velodyne_calibration import read_velodyne_calibration
from graphcal.importers.velodyne_pcap import decode_pcap, import_pcap
from graphcal.recording.directory import Recording

REAL = Path(__file__).resolve().parents[2] / "shared/data/real"
VELOVIEW = REAL / "veloview_hdl32e_vlp16_pcap"
MONTEREY = VELOVIEW / "monterey-first-100-packets.pcap"
VLP16 = VELOVIEW / "vlp-16-test-90deg-1-50-frames.pcap"
CALIBRATIONS = REAL / "ros_velodyne_calibrations"
needs_real = pytest.mark.skipif(not VELOVIEW.is_dir(), reason="shared real data absent")
needs_calibrations = pytest.mark.skipif(not CALIBRATIONS.is_dir(), reason="shared real calibrations absent")


def _write(tmp_path, capture, name="capture.pcap") -> Path:
    path = tmp_path / name
    path.write_bytes(capture.pcap if hasattr(capture, "pcap") else capture)
    return path


def _veloview_xyz(sensor, returns, mask):
    """graphcal's model on stored raw values, in VeloView's axes (x right, y forward at azimuth 0)."""
    xyz = sensor.to_xyz(returns["fibre"][mask].astype(int), returns["range"][mask].astype(np.float64),
                        returns["azimuth"][mask].astype(np.float64))
    return np.column_stack([-xyz[:, 1], xyz[:, 0], xyz[:, 2]])


def _rounded_azimuth(azimuth_rad):
    """Azimuth rounded to the packet's 0.01 deg, as velodyne-decoder does after interpolating."""
    return np.radians(np.mod(np.round(np.degrees(np.asarray(azimuth_rad, dtype=np.float64)) * 100), 36000) / 100)


def test_hdl32e_raw_values_times_and_revolutions(tmp_path):
    """Every stored value against the ground truth written into the packets (HDL-32E manual timing)."""
    capture = spinning_capture(n_packets=40, packet_us=552.96, block_step=19.9)
    decoded = decode_pcap(_write(tmp_path, capture), quiet=True)
    returns = decoded.returns
    assert decoded.model == "HDL-32E" and not decoded.dual_return
    packet, block, channel = np.nonzero(capture.distance)  # C order = packet, block, channel order
    fire_us = block * 46.08 + channel * 1.152
    np.testing.assert_allclose(returns["time_s"], (capture.stamp_us[packet] + fire_us) * 1e-6, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(returns["fibre"], channel)
    np.testing.assert_allclose(returns["range"], capture.distance[packet, block, channel] * 0.002, rtol=1e-7)
    np.testing.assert_array_equal(returns["intensity"], capture.intensity[packet, block, channel])
    step = np.mod(capture.azimuth[:, 11] - capture.azimuth[:, 0], 36000) / (11 * 46.08)  # 0.01 deg per us
    expected = np.radians(np.mod(capture.azimuth[packet, block] + step[packet] * channel * 1.152, 36000) / 100)
    np.testing.assert_allclose(returns["azimuth"], expected, atol=2e-6)
    wraps = np.concatenate([[0], np.cumsum(np.diff(capture.azimuth.ravel()) < 0)]).reshape(-1, 12)
    np.testing.assert_array_equal(returns["scan"], wraps[packet, block])
    assert returns["scan"].max() >= 1  # the capture crosses azimuth 0
    assert abs(decoded.rotation_hz - 19.9 / 46.08 * 1e6 / 36000) < 0.01


SYNTHETIC = {  # model: (capture settings, velodyne-decoder model, calibration file)
    "HDL-32E": ({"packet_us": 552.96, "block_step": 19.9}, vd.Model.HDL32E, "params/32db.yaml"),
    "HDL-32E dual": ({"packet_us": 276.48, "block_step": 19.9, "pair_blocks": 2, "mode": 0x39}, vd.Model.HDL32E,
                     "params/32db.yaml"),
    "VLP-16": ({"packet_us": 1327.104, "block_step": 39.8, "product": 0x22}, vd.Model.VLP16, "params/VLP16db.yaml"),
    "HDL-64E": ({"packet_us": 288.0, "block_step": 17.3, "pair_blocks": 2, "flags": [0xEEFF, 0xDDFF] * 6,
                 "product": 0x00}, vd.Model.HDL64E_S2, "params/64e_s2.1-sztaki.yaml"),
}


@needs_calibrations
@pytest.mark.parametrize("case", sorted(SYNTHETIC))
def test_model_reproduces_velodyne_decoder_xyz(case, tmp_path):
    """Stored raw values -> graphcal's sensor model (eq. 4.2 + factory terms) -> xyz equals the
    reference decoder's with the same calibration file, to 0.1 mm. The decoder rounds each
    interpolated azimuth to 0.01 deg: its azimuth must be ours rounded down or up. HDL-64E: the
    two-point range correction is switched off (graphcal drops it) and the decoder's convention
    for the vertical offset is added (decoder_minus_model)."""
    settings, vd_model, calibration_file = SYNTHETIC[case]
    calibration_path = CALIBRATIONS / calibration_file
    if case == "HDL-64E":
        data = yaml.safe_load(calibration_path.read_text())
        for laser in data["lasers"]:
            laser["two_pt_correction_available"] = False
            laser["dist_correction_x"] = laser["dist_correction_y"] = laser["dist_correction"]
        calibration_path = tmp_path / "64e.yaml"
        calibration_path.write_text(yaml.safe_dump(data))
    capture = spinning_capture(n_packets=60, seed=3, **settings)
    pcap = _write(tmp_path, capture)
    recording = import_pcap(pcap, tmp_path / "rec", calibration=read_velodyne_calibration(calibration_path),
                            position=(45.0, 6.0, 300.0), quiet=True)
    stored = Recording.load(tmp_path / "rec").points.read()
    fibre, range_m = stored["fibre"].astype(int), stored["range"].astype(np.float64)
    centi_deg = np.degrees(stored["azimuth"].astype(np.float64)) * 100
    config = vd.Config()
    config.model, config.calibration = vd_model, vd.Calibration.read(str(calibration_path))
    config.min_range, config.max_range = 0.0, 1000.0
    reference = np.concatenate([scan.points for scan in vd.read_pcap(str(pcap), config)])[:, :3]
    assert len(reference) == len(range_m) == np.count_nonzero(capture.distance)
    tree = cKDTree(reference)
    error = np.full(len(range_m), np.inf)
    for rounding in (np.floor, np.ceil):
        azimuth = np.radians(np.mod(rounding(centi_deg), 36000) / 100)
        xyz = recording.sensor.to_xyz(fibre, range_m, azimuth) + decoder_minus_model(recording.sensor, fibre, azimuth)
        error = np.minimum(error, tree.query(xyz)[0])
    assert error.max() < 1e-4, error.max()
    assert recording.sensor.model == case.split()[0] and recording.source["model"] == case.split()[0]


def _first_return_us(capture) -> float:
    """Sensor time of the first non-zero return of an HDL-32E capture [us past the hour]."""
    packet, block, channel = (int(index[0]) for index in np.nonzero(capture.distance))
    return capture.stamp_us[packet] + block * 46.08 + channel * 1.152


def test_gprmc_time_base_is_gps_seconds_of_week(tmp_path):
    """Sensor time past the hour + the UTC hour from $GPRMC + 18 leap seconds (2021) -> GPS week seconds."""
    stamp_s = 17 * 60 + 6.2  # 10:17:06.2 on the sensor clock
    sentence = "$GPRMC,101705,A,4851.3000,N,00221.0000,E,000.0,000.0,040321,,,A"
    fix = (1614853025.0, udp_frame(position_packet(int(stamp_s * 1e6), sentence), 8308))
    other = (1614853025.1, udp_frame(b"\x00" * 100, 9999))  # neither lidar data nor a position packet
    capture = spinning_capture(n_packets=20, packet_us=552.96, block_step=19.9, start_us=int(stamp_s * 1e6),
                               extra=[fix, other])
    recording = import_pcap(_write(tmp_path, capture), tmp_path / "rec", quiet=True)
    utc = calendar.timegm((2021, 3, 4, 10, 0, 0)) + _first_return_us(capture) * 1e-6
    gps = utc - calendar.timegm((1980, 1, 6, 0, 0, 0)) + 18.0
    week = int(gps // 604800)
    time = recording.points.read(["time"])["time"]
    assert recording.source["gps_week"] == week == 2147
    assert time[0] == pytest.approx(gps - week * 604800, abs=1e-6)
    trajectory = recording.trajectory
    np.testing.assert_allclose(trajectory.position[0], [48 + 51.3 / 60, 2 + 21 / 60, 0.0])
    assert trajectory.time[0] <= time[0] and trajectory.time[-1] >= time[-1]
    assert any("STATIC" in note for note in recording.source["notes"])
    assert any("GPRMC" in note for note in recording.source["notes"])
    assert "1 other records skipped (neither lidar data nor position packets)" in recording.source["notes"]


def test_no_fix_needs_a_position_and_uses_the_host_clock_hour(tmp_path):
    capture = spinning_capture(n_packets=10, packet_us=552.96, block_step=19.9, host_start_s=1614853000.0)
    pcap = _write(tmp_path, capture)
    with pytest.raises(RecordingError, match="--position"):
        import_pcap(pcap, tmp_path / "rec", quiet=True)
    assert not (tmp_path / "rec").exists()
    recording = import_pcap(pcap, tmp_path / "rec", position=(48.0, 2.0, 50.0), attitude_deg=(0.0, 0.0, 30.0),
                            quiet=True)
    host_hour = 3600 * np.round(1614853000.0 / 3600)  # first packet: host clock 1614853000 s + its sensor time
    gps = host_hour + _first_return_us(capture) * 1e-6 - calendar.timegm((1980, 1, 6, 0, 0, 0)) + 18
    assert recording.points.read(["time"])["time"][0] == pytest.approx(gps % 604800, abs=1e-6)
    assert any("host clock" in note for note in recording.source["notes"])
    np.testing.assert_allclose(recording.trajectory.rpy_deg[0], [0.0, 0.0, 30.0])


def test_bad_captures_get_one_clear_error(tmp_path):
    capture = spinning_capture(n_packets=5, packet_us=552.96, block_step=19.9)
    path = _write(tmp_path, capture.pcap[:-100], "cut.pcap")  # a crashed capture: its last record cut short
    cut = decode_pcap(path, quiet=True)
    whole = decode_pcap(_write(tmp_path, capture.pcap, "whole.pcap"), quiet=True)
    assert cut.n_data_packets == whole.n_data_packets - 1 and cut.cut_bytes == 16 + 1148
    np.testing.assert_array_equal(cut.returns["range"], whole.returns["range"][:len(cut.returns["range"])])
    junk = pcap_file([(1.0, udp_frame(bytes(range(256)) * 4 + bytes(182), 2368))])
    with pytest.raises(RecordingError, match=r"data packet 0 \(record 0\), block 0: flag 0x0100"):
        decode_pcap(_write(tmp_path, junk, "junk.pcap"), quiet=True)
    with pytest.raises(RecordingError, match="no Velodyne data packet among 1 records"):
        decode_pcap(_write(tmp_path, pcap_file([(1.0, udp_frame(b"hello", 53))]), "dns.pcap"), quiet=True)
    with pytest.raises(RecordingError, match="pcapng"):
        decode_pcap(_write(tmp_path, b"\x0a\x0d\x0d\x0a" + bytes(60), "x.pcapng"), quiet=True)
    with pytest.raises(RecordingError, match="snap length"):
        decode_pcap(_write(tmp_path, pcap_file([(1.0, udp_frame(bytes(1206), 2368))], captured=600), "snap.pcap"),
                    quiet=True)
    good = _write(tmp_path, capture, "good.pcap")
    with pytest.raises(RecordingError, match="every 553.0 us, where a VLP-16 sends one every 1327.1 us"):
        decode_pcap(good, model="VLP-16", quiet=True)
    with pytest.raises(RecordingError, match="HDL-64E forced, but the packets have no HDL-64E lower-block"):
        decode_pcap(good, model="HDL-64E", quiet=True)
    with pytest.raises(ConfigError, match="unknown Velodyne model 'HDL-16'"):
        decode_pcap(good, model="HDL-16", quiet=True)
    with pytest.raises(RecordingError, match="HDL-64E packets and no calibration"):
        hdl64 = spinning_capture(n_packets=5, packet_us=288.0, block_step=17.3, pair_blocks=2, flags=[0xEEFF, 0xDDFF] * 6)
        import_pcap(_write(tmp_path, hdl64, "64.pcap"), tmp_path / "rec", position=(0.0, 0.0, 0.0), quiet=True)


# --- real samples ---------------------------------------------------------------------------------------

@needs_real
def test_monterey_frames_and_points_match_veloview():
    """VeloView's expected monterey.test: 19 frames (split at the azimuth wrap), point counts, and
    four points of frame 8 from graphcal's model with VeloView's HDL-32.xml. VeloView 3 gives each
    laser its block azimuth: interpolate_azimuth=False."""
    decoded = decode_pcap(MONTEREY, interpolate_azimuth=False, quiet=True)
    counts = np.bincount(decoded.returns["scan"])
    assert len(counts) == 19
    assert [counts[i] for i in (0, 2, 8, 11, 18)] == [27649, 49485, 49737, 49778, 396]
    sensor = read_velodyne_calibration(VELOVIEW / "calib/HDL-32.xml").sensor
    frame = decoded.returns["scan"] == 8
    xyz = _veloview_xyz(sensor, decoded.returns, frame)
    expected = {1: (0.0218793, 7.83493, -1.28724, 1), 4000: (4.3412700, 8.20269, -1.97267, 28),
                16000: (77.6108000, -26.72350, 3.82785, 63), 49733: (-0.0050133, 5.74481, -1.79261, 1)}
    for index, (x, y, z, intensity) in expected.items():
        np.testing.assert_allclose(xyz[index], [x, y, z], atol=1e-4)  # the file's 6 significant digits
        assert decoded.returns["intensity"][frame][index] == intensity


@needs_real
def test_vlp16_needs_its_model_forced_and_matches_veloview():
    with pytest.raises(RecordingError, match=r"factory byte says 0x21.*--model VLP-16"):
        decode_pcap(VLP16, quiet=True)
    decoded = decode_pcap(VLP16, model="VLP-16", interpolate_azimuth=False, quiet=True)
    counts = np.bincount(decoded.returns["scan"])
    assert len(counts) == 52 and [counts[i] for i in (0, 2, 16, 51)] == [5736, 13898, 13860, 274]
    sensor = read_velodyne_calibration(VELOVIEW / "calib/VLP-16.xml").sensor
    frame = decoded.returns["scan"] == 16
    xyz = _veloview_xyz(sensor, decoded.returns, frame)
    # VeloView's second firing sequence azimuth comes from integer block steps: 0.2 mm off here
    np.testing.assert_allclose(xyz[0], [0.0801272, 6.04037, -1.61865], atol=1e-4)
    np.testing.assert_allclose(xyz[13859], [-0.0308793, 4.91453, 1.31687], atol=5e-4)
    assert decoded.returns["intensity"][frame][[0, 13859]].tolist() == [4, 29]


@needs_real
@needs_calibrations
def test_monterey_matches_velodyne_decoder():
    """The real HDL-32E capture: same returns, times and xyz as velodyne-decoder 3.1 with the same
    calibration. The stored azimuth is not rounded to 0.01 deg: with it, xyz differ by at most the
    rounding (0.005 deg x range)."""
    calibration = CALIBRATIONS / "params/32db.yaml"
    decoded = decode_pcap(MONTEREY, quiet=True)
    config = vd.Config()
    config.model, config.calibration = vd.Model.HDL32E, vd.Calibration.read(str(calibration))
    scans = list(vd.read_pcap(str(MONTEREY), config))
    reference = np.concatenate([scan.points for scan in scans])
    returns = decoded.returns
    kept = (returns["range"] >= config.min_range) & (returns["range"] <= config.max_range)
    assert kept.sum() == len(reference) == 872800
    sensor = read_velodyne_calibration(calibration).sensor
    fibre, range_m = returns["fibre"][kept].astype(int), returns["range"][kept].astype(np.float64)
    rounded = sensor.to_xyz(fibre, range_m, _rounded_azimuth(returns["azimuth"][kept]))
    assert np.abs(rounded - reference[:, :3]).max() < 2e-4
    exact = sensor.to_xyz(fibre, range_m, returns["azimuth"][kept].astype(np.float64))
    bound = range_m * np.radians(0.005) + 2e-4
    assert np.all(np.linalg.norm(exact - reference[:, :3], axis=1) <= bound)
    device_time = np.concatenate([scan.stamp.device + scan.points[:, 4].astype(np.float64) for scan in scans])
    np.testing.assert_allclose(decoded.host_hour_utc_s + returns["time_s"][kept], device_time, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(returns["intensity"][kept], reference[:, 3])


@needs_real
def test_monterey_import_writes_a_valid_recording(tmp_path):
    import_pcap(MONTEREY, tmp_path / "monterey", calibration=read_velodyne_calibration(VELOVIEW / "calib/HDL-32.xml"),
                quiet=True)
    loaded = Recording.load(tmp_path / "monterey")
    summary = loaded.validate()
    assert summary.n_points == 872800 and loaded.sensor.model == "HDL-32E"
    # GPRMC 2012-12-11 22:06:32 UTC, sensor 393.203883 s past 22:00, GPS - UTC = 16 s
    first = calendar.timegm((2012, 12, 11, 22, 0, 0)) + 393.203883 - calendar.timegm((1980, 1, 6, 0, 0, 0)) + 16
    assert loaded.source["gps_week"] == 1718
    assert summary.time_min == pytest.approx(first - 1718 * 604800, abs=1e-6)
    np.testing.assert_allclose(loaded.trajectory.position[0, :2], [37.13054, -121.6547733], atol=1e-6)
    assert loaded.sensor.rotation_hz == pytest.approx(11.78, abs=0.01)


@needs_calibrations
@pytest.mark.parametrize("unit", ["32db", "64e_s2.1-sztaki"])
def test_db_xml_and_its_ros_yaml_give_the_same_model(unit):
    """The ROS YAML files are gen_calibration.py conversions of the db.xml: same nominal model."""
    xml = read_velodyne_calibration(CALIBRATIONS / f"db_xml_and_test_yaml/{unit}.xml")
    ros = read_velodyne_calibration(CALIBRATIONS / f"params/{unit}.yaml")
    for name in ("elevation_deg", "azimuth_offset_deg", "range_offset_m", "vertical_offset_m", "horizontal_offset_m"):
        np.testing.assert_allclose(getattr(xml.sensor, name), getattr(ros.sensor, name), atol=1e-6)
    assert xml.distance_resolution_m == ros.distance_resolution_m == 0.002
    assert xml.dropped_two_point_m == pytest.approx(ros.dropped_two_point_m, abs=1e-6)
    if unit == "32db":
        assert xml.sensor.n_fibres == 32 and xml.notes() == []
        np.testing.assert_allclose(xml.sensor.elevation_deg, read_velodyne_calibration(
            CALIBRATIONS / "params/32db.yaml", model="HDL-32E").sensor.elevation_deg)
    else:
        assert xml.sensor.model == "HDL-64E" and xml.sensor.n_fibres == 64
        assert 0.1 < xml.dropped_two_point_m < 0.12 and "two-point" in xml.notes()[0]
        laser0 = xml.sensor  # db.xml: rotCorrection -7.1559157 deg, distCorrection 151.95264 cm, vertOffset 19.548199 cm
        assert (laser0.azimuth_offset_deg[0], laser0.range_offset_m[0]) == pytest.approx((7.1559157, 1.5195264))
        assert laser0.vertical_offset_m[0] == pytest.approx(0.19548199)


def test_bad_calibration_files(tmp_path):
    broken = tmp_path / "db.xml"
    broken.write_text("<boost_serialization><DB><points_>")
    with pytest.raises(RecordingError, match=r"db\.xml: not valid XML"):
        read_velodyne_calibration(broken)
    ros = tmp_path / "calib.yaml"
    ros.write_text("lasers:\n- {laser_id: 0, vert_correction: 0.1}\n- {laser_id: 2, vert_correction: 0.2}\n")
    with pytest.raises(RecordingError, match=r"field 'laser_id': laser ids \[0, 2\]"):
        read_velodyne_calibration(ros)
    ros.write_text("lasers:\n- {laser_id: 0, vert_correction: zero}\n")
    with pytest.raises(RecordingError, match=r"lasers\[0\]\.vert_correction"):
        read_velodyne_calibration(ros)
    with pytest.raises(RecordingError, match="16 lasers for a VLP-16"):
        ros.write_text("lasers:\n- {laser_id: 0, vert_correction: 0.1}\n")
        read_velodyne_calibration(ros, model="VLP-16")
    ros.write_text("lasers:\n- {laser_id: 0, vert_correction: 0.1}\n- {laser_id: 1.7, vert_correction: 0.2}\n")
    with pytest.raises(RecordingError, match=r"field 'laser_id', row 1: laser_id 1.7.*an integer"):
        read_velodyne_calibration(ros)
    broken.write_text("<boost_serialization><DB><enabled_><item>1</item><item></item></enabled_>"
                      "<points_><item><px><id_>0</id_><vertCorrection_>0.1</vertCorrection_></px></item></points_>"
                      "</DB></boost_serialization>")
    with pytest.raises(RecordingError, match=r"field 'enabled_', row 1: missing value"):
        read_velodyne_calibration(broken)


NEBULA = REAL / "nebula_velodyne_rosbag2"


@pytest.mark.skipif(not NEBULA.is_dir(), reason="shared real data absent")
def test_rosbag_vlp16_dual_return_matches_velodyne_decoder(tmp_path):
    """nebula's real VLP-16 bag (ROS 2, dual return): the packets read with rosbags, decoded by
    graphcal, through graphcal's model, equal velodyne-decoder's points fed the same packets."""
    pytest.importorskip("rosbags")
    from graphcal.importers.velodyne_rosbag import (
        decode_rosbag,
        import_rosbag,
        read_velodyne_packets,
    )

    bag, calibration = NEBULA / "vlp16/1673400471837873222", NEBULA / "calibration/VLP16.yaml"
    decoded = decode_rosbag(bag, quiet=True)
    assert decoded.model == "VLP-16" and decoded.dual_return and decoded.n_data_packets == 603
    packets, stamps = read_velodyne_packets(bag)
    reference = reference_xyz(packets, stamps, "VLP16", calibration)
    returns = decoded.returns
    assert len(reference) == len(returns["range"]) == 59414
    sensor = read_velodyne_calibration(calibration).sensor
    fibre, range_m = returns["fibre"].astype(int), returns["range"].astype(np.float64)
    centi_deg, tree, error = np.degrees(returns["azimuth"].astype(np.float64)) * 100, cKDTree(reference), np.inf
    for rounding in (np.floor, np.ceil):
        xyz = sensor.to_xyz(fibre, range_m, np.radians(np.mod(rounding(centi_deg), 36000) / 100))
        error = np.minimum(error, tree.query(xyz)[0])
    assert error.max() < 1e-4
    with pytest.raises(RecordingError, match="--position"):
        import_rosbag(bag, tmp_path / "rec", quiet=True)
    recording = import_rosbag(bag, tmp_path / "rec", position=(35.6, 139.7, 40.0), quiet=True)
    assert recording.source["importer"] == "velodyne-rosbag" and any("ROS packet stamps" in n for n in
                                                                     recording.source["notes"])
    with pytest.raises(RecordingError, match=r"no velodyne_msgs/msg/VelodyneScan topic named /points"):
        read_velodyne_packets(bag, topic="/points")


def test_dual_return_duplicates_are_one_return(tmp_path):
    """A second return equal to the first (distance and intensity) is the same return twice."""
    capture = spinning_capture(n_packets=10, packet_us=276.48, block_step=19.9, pair_blocks=2, mode=0x39)
    capture.distance[:, 1::2, :8] = capture.distance[:, 0::2, :8]
    capture.intensity[:, 1::2, :8] = capture.intensity[:, 0::2, :8]
    records = [(1.0 + 1e-3 * p, udp_frame(data_packet(capture.azimuth[p], capture.distance[p], capture.intensity[p],
                                                      int(capture.stamp_us[p]), mode=0x39), 2368))
               for p in range(10)]
    decoded = decode_pcap(_write(tmp_path, pcap_file(records)), quiet=True)
    duplicates = np.count_nonzero(capture.distance[:, 1::2, :8])
    assert duplicates > 0 and len(decoded.returns["range"]) == np.count_nonzero(capture.distance) - duplicates


def _same_recordings(first: Path, second: Path) -> None:
    """Two recording folders with equal points.parquet columns and equal files beside them."""
    a, b = Recording.load(first).points.read(), Recording.load(second).points.read()
    assert list(a) == list(b)
    for name in a:
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)
    for name in ("sensor.yaml", "extrinsic.yaml", "recording.yaml", "trajectory.csv"):
        assert (first / name).read_text() == (second / name).read_text(), name


def test_pcap_read_a_record_at_a_time_gives_the_same_recording(tmp_path, monkeypatch):
    """A dual-return capture across the top of the hour, GPRMC packets before the first data packet and between
    data packets, read 1,300 bytes (one record or none) at a time: chunks without a data packet, each packet's
    successor in the next chunk. points.parquet (row groups of 5,000 rows) and the files beside it are those of
    the whole file read at once."""
    monkeypatch.setattr("graphcal.recording.points.BATCH_ROWS", 5000)
    capture = spinning_capture(n_packets=60, packet_us=276.48, block_step=19.9, pair_blocks=2, mode=0x39)
    start_us = 3_600_000_000 - 30 * 276  # the sensor's hour turns after 30 packets
    stamps = (start_us + capture.stamp_us - capture.stamp_us[0]).astype(np.int64)
    host_s = 1614855600.0 - 30 * 276e-6  # 2021-03-04 11:00:00 UTC at the turn
    records = [(host_s + (stamps[p] - start_us) * 1e-6,
                udp_frame(data_packet(capture.azimuth[p], capture.distance[p], capture.intensity[p],
                                      int(stamps[p] % 3_600_000_000), mode=0x39), 2368)) for p in range(60)]
    for host, stamp_us, sentence in ((host_s - 0.5, start_us - 500_000, "$GPRMC,105958,A,4851.3000,N,00221.0000,E,"
                                                                        "000.0,000.0,040321,,,A"),
                                     (host_s + 0.012, 3000, "$GPRMC,110000,A,4851.3020,N,00221.0010,E,000.0,000.0,"
                                                            "040321,,,A")):
        records.append((host, udp_frame(position_packet(stamp_us, sentence), 8308)))
    pcap = _write(tmp_path, pcap_file(sorted(records, key=lambda record: record[0])))
    import_pcap(pcap, tmp_path / "chunked", chunk_bytes=1300, quiet=True)
    whole = import_pcap(pcap, tmp_path / "whole", chunk_bytes=None, quiet=True)
    _same_recordings(tmp_path / "chunked", tmp_path / "whole")
    assert len(whole.points) == np.count_nonzero(capture.distance) and whole.points._file.metadata.num_row_groups > 2
    assert any("mean of 2 GPRMC fixes" in note for note in whole.source["notes"])
    time = whole.points.read(["time"])["time"]
    assert np.all(np.diff(time) >= 0) and np.ptp(time) < 0.02  # no hour lost at the turn


@needs_real
def test_monterey_read_in_small_chunks_gives_the_same_recording(tmp_path):
    """The real capture read 4,000 bytes (three records) at a time: the same recording as the whole file at once."""
    import_pcap(MONTEREY, tmp_path / "chunked", chunk_bytes=4000, quiet=True)
    import_pcap(MONTEREY, tmp_path / "whole", chunk_bytes=None, quiet=True)
    _same_recordings(tmp_path / "chunked", tmp_path / "whole")
