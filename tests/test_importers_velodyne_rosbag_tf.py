"""`import pcap BAG` on rosbag2 bags the test writes with rosbags: VelodyneScan messages of synthetic HDL-32E
packets (velodyne_synth), /tf_static and /tf transforms and an Odometry topic; the extrinsic comes from the bag's tf
(from --body-frame or the Odometry's child frame to the packets' header.frame_id), a command-line one wins, a
broken chain is named in the notes."""

import numpy as np
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from graphcal.cli.main import app
from graphcal.importers.velodyne_rosbag import _DEFINITIONS, SCAN_TYPE, import_rosbag
from graphcal.recording.directory import Recording
from test_importers_pointcloud2 import BASE_ROOF, ROOF_VELODYNE, TF, _header, _odom_base_link, _odometry, _stamp, _tf
from velodyne_synth import data_packet

POSITION = (48.85, 2.35, 50.0)
HOST_S = 1614853000.0  # ROS stamp of the first packet [s since 1970]
PACKET_S = 552.96e-6  # HDL-32E


def _scans(store, n_messages=4, per_message=10, frame="velodyne", seed=0):
    """VelodyneScan messages of HDL-32E packets spinning at about 10 Hz: (stamp s, message)."""
    rng = np.random.default_rng(seed)
    messages = []
    for m in range(n_messages):
        packets = []
        for k in range(per_message):
            p = m * per_message + k
            azimuth = np.round(34000 + 19.9 * (12 * p + np.arange(12))).astype(np.int64) % 36000
            distance, intensity = rng.integers(250, 65_000, (12, 32)), rng.integers(0, 256, (12, 32))
            stamp_us = 1_000_000 + round(p * PACKET_S * 1e6)
            payload = np.frombuffer(data_packet(azimuth, distance, intensity, stamp_us), dtype=np.uint8)
            packets.append(store.types["velodyne_msgs/msg/VelodynePacket"](
                stamp=_stamp(store, HOST_S + p * PACKET_S), data=payload))
        t = HOST_S + (m + 1) * per_message * PACKET_S
        messages.append((t, store.types[SCAN_TYPE](header=_header(store, t, frame), packets=packets)))
    return messages


def _write_bag(path, tf=(), odometry=True, frame="velodyne", storage=StoragePlugin.SQLITE3):
    """A rosbag2 of VelodyneScan messages on /velodyne_packets, the TFMessages (topic, time, transforms) of tf and,
    with odometry, nav_msgs/Odometry of base_link in odom."""
    store = get_typestore(Stores.ROS2_HUMBLE)
    for name, definition in _DEFINITIONS.items():
        store.register(get_types_from_msg(definition, name))
    messages = [("/velodyne_packets", SCAN_TYPE, t, msg) for t, msg in _scans(store, frame=frame)]
    messages += [(topic, TF, t, _tf(store, t, transforms)) for topic, t, transforms in tf]
    if odometry:
        times = HOST_S - 0.05 + 0.05 * np.arange(4)
        messages += [("/odom", "nav_msgs/msg/Odometry", t, msg) for t, msg in _odometry(store, times)]
    messages.sort(key=lambda m: m[2])
    with Writer2(path, version=9, storage_plugin=storage) as writer:
        connections = {}
        for topic, msgtype, t, msg in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(connections[topic], round(t * 1e9), store.serialize_cdr(msg, msgtype))
    return path


def _base_velodyne():
    """T_base_link_velodyne = T_base_link_roof T_roof_velodyne, composed with scipy."""
    (_, _, t_a, rpy_a), (_, _, t_b, rpy_b) = BASE_ROOF, ROOF_VELODYNE
    R_a = Rotation.from_euler("ZYX", rpy_a[::-1], degrees=True)
    R_b = Rotation.from_euler("ZYX", rpy_b[::-1], degrees=True)
    return R_a * R_b, R_a.apply(t_b) + np.array(t_a)


def test_tf_static_chain_from_the_odometry_frame_is_the_extrinsic_unless_one_is_given(tmp_path):
    """base_link -> roof -> velodyne on /tf_static (two messages), odom -> base_link moving on /tf, Odometry of
    base_link: the recording's extrinsic is T_base_link_velodyne; --lever-arm on the command line wins."""
    t0 = HOST_S - 0.05
    tf = [("/tf_static", t0, [BASE_ROOF]), ("/tf_static", t0, [ROOF_VELODYNE]),
          _odom_base_link(t0, 0.0), _odom_base_link(t0 + 0.01, 0.5)]
    bag = _write_bag(tmp_path / "drive", tf=tf)
    recording = import_rosbag(bag, tmp_path / "rec", position=POSITION, quiet=True)
    rotation, translation = _base_velodyne()
    np.testing.assert_allclose(recording.extrinsic.lever_arm_m, translation, atol=1e-12)
    np.testing.assert_allclose(recording.extrinsic.R_body_lidar, rotation.as_matrix(), atol=1e-12)
    assert any("from the bag's tf: base_link -> roof -> velodyne" in n for n in recording.source["notes"])
    assert recording.source["importer"] == "velodyne-rosbag" and len(recording.points) > 0
    result = CliRunner().invoke(app, ["import", "pcap", str(bag), "--position", "48.85,2.35,50", "--lever-arm",
                                      "1,2,3", "--out", str(tmp_path / "given"), "-q"])
    assert result.exit_code == 0, result.output
    given = Recording.load(tmp_path / "given")
    assert given.extrinsic.lever_arm_m == (1.0, 2.0, 3.0) and given.extrinsic.boresight_deg == (0.0, 0.0, 0.0)
    assert any("extrinsic as given" in n for n in given.source["notes"])
    # the same points whichever extrinsic: the tf only sets extrinsic.yaml and a note
    assert (tmp_path / "given" / "points.parquet").read_bytes() == (tmp_path / "rec" / "points.parquet").read_bytes()


def test_body_frame_names_the_body_when_the_bag_has_no_odometry(tmp_path):
    """Without Odometry (an MCAP rosbag2) the body has no name in the bag: the tf is not read and the note says how
    to read it; with --body-frame /base_link the extrinsic is T_base_link_velodyne."""
    bag = _write_bag(tmp_path / "drive", tf=[("/tf_static", HOST_S - 0.05, [BASE_ROOF, ROOF_VELODYNE])],
                     odometry=False, storage=StoragePlugin.MCAP)
    args = ["import", "pcap", str(bag), "--position", "48.85,2.35,50", "-q"]
    result = CliRunner().invoke(app, [*args, "--out", str(tmp_path / "unnamed")])
    assert result.exit_code == 0, result.output
    unnamed = Recording.load(tmp_path / "unnamed")
    assert unnamed.extrinsic.lever_arm_m == (0.0, 0.0, 0.0)
    assert any("identity" in n and "--body-frame" in n for n in unnamed.source["notes"])
    result = CliRunner().invoke(app, [*args, "--body-frame", "/base_link", "--out", str(tmp_path / "named")])
    assert result.exit_code == 0, result.output
    named = Recording.load(tmp_path / "named")
    rotation, translation = _base_velodyne()
    np.testing.assert_allclose(named.extrinsic.lever_arm_m, translation, atol=1e-12)
    np.testing.assert_allclose(named.extrinsic.R_body_lidar, rotation.as_matrix(), atol=1e-12)


def test_broken_tf_chain_is_named_and_the_extrinsic_stays_identity(tmp_path):
    """Static transforms that do not link base_link to the packets' frame (given with tf's leading '/'): the
    extrinsic is identity and the notes name both frames and the transforms found."""
    tf = [("/tf_static", HOST_S - 0.05, [("base_link", "roof", *BASE_ROOF[2:]),
                                         ("mount", "velodyne", *ROOF_VELODYNE[2:])])]
    bag = _write_bag(tmp_path / "drive", tf=tf, frame="/velodyne")
    recording = import_rosbag(bag, tmp_path / "rec", position=POSITION, quiet=True)
    assert recording.extrinsic.lever_arm_m == (0.0, 0.0, 0.0) and recording.extrinsic.boresight_deg == (0.0, 0.0, 0.0)
    note = next(n for n in recording.source["notes"] if "extrinsic" in n)
    assert "identity" in note and "does not link base_link" in note, note
    assert "to velodyne (the VelodyneScan messages' header.frame_id)" in note, note
    assert "transforms found: base_link -> roof, mount -> velodyne" in note, note


def test_body_frame_with_a_pcap_file_is_a_clear_error(tmp_path):
    """--body-frame names a frame of a bag's tf: with a libpcap file, one line naming the option and the file."""
    capture = tmp_path / "drive.pcap"
    capture.write_bytes(b"\xd4\xc3\xb2\xa1" + bytes(20))
    result = CliRunner().invoke(app, ["import", "pcap", str(capture), "--body-frame", "base_link", "--out",
                                      str(tmp_path / "rec")])
    assert result.exit_code == 2 and "--body-frame: only for a ROS bag" in result.output, result.output
    assert result.output.count("\n") == 1 and not (tmp_path / "rec").exists()
