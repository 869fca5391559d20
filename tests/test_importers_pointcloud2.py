"""`import pointcloud2` on bags the test writes with rosbags (rosbag1, rosbag2 sqlite3, rosbag2 mcap, a standalone
MCAP file) from synthetic scans with known raw returns, in the velodyne_pointcloud and ouster-ros point layouts,
with the trajectory from NavSatFix + Imu, from Odometry, or from a trajectory.csv, and the extrinsic from the bag's
/tf_static."""

import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

import ring_scans_synth as synth
from graphcal.cli.main import app
from graphcal.common.errors import RecordingError
from graphcal.importers.gpstime import seconds_of_week
from graphcal.importers.pointcloud2 import import_pointcloud2
from graphcal.importers.velodyne_calibration import read_velodyne_calibration
from graphcal.recording.directory import Recording
from graphcal.recording.trajectory import Trajectory

CLOUD = "sensor_msgs/msg/PointCloud2"
TF = "tf2_msgs/msg/TFMessage"
# PointField datatypes
F32, F64, U16, U32 = 7, 8, 4, 6
VELODYNE = [("x", F32), ("y", F32), ("z", F32), ("intensity", F32), ("ring", U16), ("time", F32)]
OUSTER = [("x", F32), ("y", F32), ("z", F32), ("intensity", F32), ("t", U32), ("reflectivity", U16),
          ("ring", U16), ("ambient", U16), ("range", U32)]
ABSOLUTE = [("x", F32), ("y", F32), ("z", F32), ("intensity", F32), ("ring", U16), ("timestamp", F64)]
_NUMPY = {F32: "<f4", F64: "<f8", U16: "<u2", U32: "<u4"}
LAT, LON, ALT = 48.85, 2.35, 50.0


def _stamp(store, seconds: float):
    return store.types["builtin_interfaces/msg/Time"](sec=int(seconds), nanosec=round((seconds % 1) * 1e9))


def _header(store, seconds: float, frame: str):
    kwargs = {"seq": 0} if "seq" in store.types["std_msgs/msg/Header"].__dataclass_fields__ else {}
    return store.types["std_msgs/msg/Header"](stamp=_stamp(store, seconds), frame_id=frame, **kwargs)


def _cloud(store, scan: dict, layout, model, frame: str = "lidar") -> object:
    """A PointCloud2 of one synthetic scan in a driver's layout (Ouster: ring 0 is the top beam, t in ns)."""
    dtype = np.dtype([(name, _NUMPY[kind]) for name, kind in layout])
    points = np.zeros(len(scan["time"]), dtype=dtype)
    points["x"], points["y"], points["z"] = scan["xyz"].T
    points["intensity"] = scan["intensity"]
    names = dtype.names
    points["ring"] = model.n_fibres - 1 - scan["ring"] if "t" in names else scan["ring"]
    if "t" in names:
        points["t"] = np.round((scan["time"] - scan["stamp"]) * 1e9)
    elif "time" in names:
        points["time"] = scan["time"] - scan["stamp"]
    else:
        points["timestamp"] = scan["time"]
    field = store.types["sensor_msgs/msg/PointField"]
    fields = [field(name=name, offset=dtype.fields[name][1], datatype=kind, count=1) for name, kind in layout]
    return store.types[CLOUD](header=_header(store, scan["stamp"], frame), height=1, width=len(points),
                              fields=fields, is_bigendian=False, point_step=dtype.itemsize,
                              row_step=dtype.itemsize * len(points), data=np.frombuffer(points.tobytes(), np.uint8),
                              is_dense=True, **({}))


def _navsat_imu(store, times):
    """(NavSatFix, Imu) message pairs: a slow drive north-east, heading turning."""
    msgs = []
    for k, t in enumerate(times):
        status = store.types["sensor_msgs/msg/NavSatStatus"](status=0, service=1)
        fix = store.types["sensor_msgs/msg/NavSatFix"](header=_header(store, t, "gnss"), status=status,
                                                        latitude=LAT + 1e-6 * k, longitude=LON + 2e-6 * k,
                                                        altitude=ALT, position_covariance=np.zeros(9),
                                                        position_covariance_type=0)
        q = Rotation.from_euler("ZYX", [30 + 2 * k, 1.0, 0.5], degrees=True).as_quat()
        quaternion = store.types["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3])
        vector = store.types["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
        imu = store.types["sensor_msgs/msg/Imu"](header=_header(store, t, "imu"), orientation=quaternion,
                                                  orientation_covariance=np.zeros(9), angular_velocity=vector,
                                                  angular_velocity_covariance=np.zeros(9),
                                                  linear_acceleration=vector,
                                                  linear_acceleration_covariance=np.zeros(9))
        msgs.append((t, fix, imu))
    return msgs


def _odometry(store, times):
    t_ = store.types
    out = []
    for k, t in enumerate(times):
        pose = t_["geometry_msgs/msg/Pose"](position=t_["geometry_msgs/msg/Point"](x=0.5 * k, y=0.1 * k, z=0.0),
                                             orientation=t_["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))
        twist = t_["geometry_msgs/msg/Twist"](linear=t_["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                                               angular=t_["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0))
        out.append((t, t_["nav_msgs/msg/Odometry"](
            header=_header(store, t, "odom"), child_frame_id="base_link",
            pose=t_["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
            twist=t_["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=np.zeros(36)))))
    return out


def _tf(store, t: float, transforms) -> object:
    """A TFMessage of (parent, child, translation m, roll pitch yaw deg) transforms (T_parent_child)."""
    if TF not in store.types:  # the ROS 1 store has no tf2_msgs
        store.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", TF))
    t_ = store.types
    stamped = []
    for parent, child, translation, rpy in transforms:
        q = Rotation.from_euler("ZYX", rpy[::-1], degrees=True).as_quat()
        transform = t_["geometry_msgs/msg/Transform"](translation=t_["geometry_msgs/msg/Vector3"](*translation),
                                                      rotation=t_["geometry_msgs/msg/Quaternion"](*q))
        stamped.append(t_["geometry_msgs/msg/TransformStamped"](header=_header(store, t, parent), child_frame_id=child,
                                                                transform=transform))
    return t_[TF](transforms=stamped)


def _pose_times(scans):
    return synth.START_UTC - 0.05 + 0.05 * np.arange(2 * len(scans) + 3)


def _write(path, container, scans, layout, model, trajectory, tf=(), frame="lidar", logged=None):
    """A bag of the scans (+ NavSatFix/Imu or Odometry messages) in one container; tf: (topic, time, transforms)
    of TFMessages (see _tf); frame: the clouds' header.frame_id; logged: the clouds' log times (default: their
    stamps), which set their order in the bag."""
    ros1 = container == "rosbag1"
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    logged = [scan["stamp"] for scan in scans] if logged is None else logged
    messages = [("/points", CLOUD, t, _cloud(store, scan, layout, model, frame)) for t, scan in zip(logged, scans)]
    messages += [(topic, TF, t, _tf(store, t, transforms)) for topic, t, transforms in tf]
    if trajectory == "navsat":
        for t, fix, imu in _navsat_imu(store, _pose_times(scans)):
            messages += [("/fix", "sensor_msgs/msg/NavSatFix", t, fix), ("/imu", "sensor_msgs/msg/Imu", t, imu)]
    elif trajectory == "odometry":
        messages += [("/odom", "nav_msgs/msg/Odometry", t, msg) for t, msg in _odometry(store, _pose_times(scans))]
    messages.sort(key=lambda m: m[2])
    if ros1:
        writer = Writer1(path)
    else:
        writer = Writer2(path, version=9, storage_plugin=StoragePlugin.MCAP if "mcap" in container
                         else StoragePlugin.SQLITE3)
    with writer:
        connections = {}
        for topic, msgtype, t, msg in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
            data = store.serialize_ros1(msg, msgtype) if ros1 else store.serialize_cdr(msg, msgtype)
            writer.write(connections[topic], round(t * 1e9), data)
    if container == "mcap":  # the storage file alone, without the rosbag2 folder's metadata.yaml
        return next(path.glob("*.mcap"))
    return path


def _check(recording, scans, model, fibre_known: bool):
    """The recording's returns against the true raw values (matched by time)."""
    truth = {key: np.concatenate([s[key] for s in scans]) for key in ("time", "fibre", "range", "azimuth")}
    base = np.floor(truth["time"].min())
    true_time, _ = seconds_of_week(base, truth["time"] - base, recording.source["gps_week"])
    points = recording.points.read()
    index = synth.nearest(true_time, points["time"])
    assert len(points["time"]) == len(true_time)
    np.testing.assert_allclose(points["time"], true_time[index], atol=1e-6)
    fibre = truth["fibre"][index]
    if fibre_known:
        np.testing.assert_array_equal(points["fibre"], fibre)
    np.testing.assert_allclose(recording.sensor.elevation_deg[points["fibre"]], model.elevation_deg[fibre], atol=2e-3)
    np.testing.assert_allclose(points["range"], truth["range"][index], atol=2e-4)
    np.testing.assert_allclose(np.angle(np.exp(1j * (points["azimuth"] - truth["azimuth"][index]))), 0.0, atol=2e-5)


def test_rosbag1_velodyne_layout_with_navsatfix_and_imu(tmp_path):
    model = synth.sensor(with_offsets=False)
    scans = synth.scans(model, n_scans=3)
    bag = _write(tmp_path / "drive.bag", "rosbag1", scans, VELODYNE, model, "navsat")
    recording = import_pointcloud2(bag, tmp_path / "rec", quiet=True)
    _check(recording, scans, model, fibre_known=False)
    trajectory = recording.trajectory
    assert trajectory.geodetic and recording.crs == "auto"
    np.testing.assert_allclose(trajectory.position[:, 0], LAT + 1e-6 * np.arange(len(trajectory.time)))
    np.testing.assert_allclose(trajectory.rpy_deg[:, 2], 30 + 2 * np.arange(len(trajectory.time)), atol=1e-9)
    np.testing.assert_allclose(trajectory.rpy_deg[:, :2], [[0.5, 1.0]] * len(trajectory.time), atol=1e-9)
    assert any("antenna's offset from it is not applied" in note for note in recording.source["notes"])


def test_rosbag2_sqlite3_ouster_layout_with_odometry(tmp_path):
    """Ouster's layout: t in ns from the header stamp, ring 0 the top beam."""
    model = synth.sensor(with_offsets=False)
    scans = synth.scans(model, n_scans=2, seed=4)
    bag = _write(tmp_path / "drive", "rosbag2", scans, OUSTER, model, "odometry")
    recording = import_pointcloud2(bag, tmp_path / "rec", quiet=True)
    _check(recording, scans, model, fibre_known=False)
    assert not recording.trajectory.geodetic and recording.crs.startswith("+proj=tmerc")
    np.testing.assert_allclose(recording.trajectory.position[:, 0], 0.5 * np.arange(len(recording.trajectory.time)))


def test_rosbag2_mcap_velodyne_layout_with_calibration(tmp_path):
    """The driver's model (azimuth, range and horizontal offsets) given as a calibration: raw values exact."""
    model = synth.sensor(with_offsets=True)
    scans = synth.scans(model, n_scans=2, seed=5)
    synth.write_ros_calibration(tmp_path / "calib.yaml", model)
    bag = _write(tmp_path / "drive", "rosbag2-mcap", scans, VELODYNE, model, "navsat")
    calibration = read_velodyne_calibration(tmp_path / "calib.yaml")
    recording = import_pointcloud2(bag, tmp_path / "rec", calibration=calibration, quiet=True)
    _check(recording, scans, model, fibre_known=True)


def test_mcap_file_absolute_times_with_trajectory_csv(tmp_path):
    """A standalone MCAP file, float64 absolute timestamps, the trajectory from a file (GPS seconds of week), via
    the command line."""
    model = synth.sensor(with_offsets=False)
    scans = synth.scans(model, n_scans=2, seed=6)
    bag = _write(tmp_path / "drive", "mcap", scans, ABSOLUTE, model, None)
    base = np.floor(synth.START_UTC)
    times, _ = seconds_of_week(base, _pose_times(scans) - base)
    n = len(times)
    Trajectory(times, np.column_stack([np.full(n, LAT), np.full(n, LON), np.full(n, ALT)]), np.zeros((n, 3)),
               geodetic=True).save_csv(tmp_path / "trajectory.csv")
    result = CliRunner().invoke(app, ["import", "pointcloud2", str(bag), "--trajectory", str(tmp_path / "trajectory.csv"),
                                      "--out", str(tmp_path / "rec"), "-q"])
    assert result.exit_code == 0, result.output
    recording = Recording.load(tmp_path / "rec")
    _check(recording, scans, model, fibre_known=False)
    assert result.output == ""


def test_bag_errors_name_the_bag(tmp_path):
    model = synth.sensor(with_offsets=False)
    scans = synth.scans(model, n_scans=1, columns=20)
    bag = _write(tmp_path / "drive.bag", "rosbag1", scans, VELODYNE, model, None)
    with pytest.raises(RecordingError, match="drive.bag.*no trajectory"):
        import_pointcloud2(bag, tmp_path / "rec", quiet=True)
    with pytest.raises(RecordingError, match="drive.bag.*0 sensor_msgs/msg/PointCloud2 topics named /other"):
        import_pointcloud2(bag, tmp_path / "rec", topic="/other", quiet=True)
    (tmp_path / "junk.bag").write_bytes(b"#ROSBAG V2.0\n" + b"\0" * 40)
    result = CliRunner().invoke(app, ["import", "pointcloud2", str(tmp_path / "junk.bag"), "-q"])
    assert result.exit_code == 2 and "junk.bag: not a readable ROS bag" in result.output


BASE_ROOF = ("base_link", "roof", (0.5, 0.0, 1.6), (0.0, 2.0, 0.0))  # parent, child, translation m, roll pitch yaw deg
ROOF_VELODYNE = ("roof", "velodyne", (0.3, -0.1, 0.25), (1.0, -0.5, 91.0))


def _odom_base_link(t: float, x: float):
    """A moving transform on /tf (the vehicle's pose), which the extrinsic must not take."""
    return ("/tf", t, [("odom", "base_link", (x, 0.0, 0.0), (0.0, 0.0, 0.0))])


def test_tf_static_chain_becomes_the_extrinsic_unless_one_is_given(tmp_path):
    """base_link -> roof -> velodyne on /tf_static (two messages), odom -> base_link moving on /tf: the recording's
    extrinsic is T_base_link_velodyne, composed here with scipy; --lever-arm on the command line wins."""
    model = synth.sensor(with_offsets=False)
    scans = synth.scans(model, n_scans=2, seed=7)
    t0 = synth.START_UTC - 0.05
    tf = [("/tf_static", t0, [BASE_ROOF]), ("/tf_static", t0, [ROOF_VELODYNE]),
          _odom_base_link(t0, 0.0), _odom_base_link(t0 + 0.1, 0.5)]
    bag = _write(tmp_path / "drive", "rosbag2", scans, VELODYNE, model, "odometry", tf=tf, frame="velodyne")
    recording = import_pointcloud2(bag, tmp_path / "rec", quiet=True)
    (_, _, t_a, rpy_a), (_, _, t_b, rpy_b) = BASE_ROOF, ROOF_VELODYNE
    R_base_roof = Rotation.from_euler("ZYX", rpy_a[::-1], degrees=True)
    R_roof_velodyne = Rotation.from_euler("ZYX", rpy_b[::-1], degrees=True)
    R_base_velodyne = R_base_roof * R_roof_velodyne
    t_base_velodyne = R_base_roof.apply(t_b) + np.array(t_a)
    np.testing.assert_allclose(recording.extrinsic.lever_arm_m, t_base_velodyne, atol=1e-12)
    np.testing.assert_allclose(recording.extrinsic.R_body_lidar, R_base_velodyne.as_matrix(), atol=1e-12)
    np.testing.assert_allclose(recording.extrinsic.boresight_deg,  # RECORDING.md: R = Rz(yaw) Ry(pitch) Rx(roll)
                               R_base_velodyne.as_euler("ZYX", degrees=True)[::-1], atol=1e-9)
    assert any("from the bag's tf: base_link -> roof -> velodyne" in n for n in recording.source["notes"])
    result = CliRunner().invoke(app, ["import", "pointcloud2", str(bag), "--lever-arm", "1,2,3", "--out",
                                      str(tmp_path / "given"), "-q"])
    assert result.exit_code == 0, result.output
    given = Recording.load(tmp_path / "given")
    assert given.extrinsic.lever_arm_m == (1.0, 2.0, 3.0) and given.extrinsic.boresight_deg == (0.0, 0.0, 0.0)
    assert any("extrinsic as given" in n for n in given.source["notes"])


def test_body_frame_reads_the_tf_with_a_trajectory_file(tmp_path):
    """With a trajectory file the body frame has no name in the bag: without --body-frame the tf is not read (the
    note says how to read it); with --body-frame base_link the extrinsic is T_base_link_velodyne from /tf_static."""
    model = synth.sensor(with_offsets=False)
    scans = synth.scans(model, n_scans=2, seed=9)
    t0 = synth.START_UTC - 0.05
    bag = _write(tmp_path / "drive", "rosbag2", scans, VELODYNE, model, "odometry", frame="velodyne",
                 tf=[("/tf_static", t0, [BASE_ROOF, ROOF_VELODYNE])])
    trajectory = tmp_path / "trajectory.csv"
    import_pointcloud2(bag, tmp_path / "from_bag", quiet=True).trajectory.save_csv(trajectory)
    args = ["import", "pointcloud2", str(bag), "--trajectory", str(trajectory), "--crs", "EPSG:32631", "-q"]
    result = CliRunner().invoke(app, [*args, "--out", str(tmp_path / "unnamed")])
    assert result.exit_code == 0, result.output
    unnamed = Recording.load(tmp_path / "unnamed")
    assert unnamed.extrinsic.lever_arm_m == (0.0, 0.0, 0.0)
    assert any("--body-frame" in n for n in unnamed.source["notes"])
    result = CliRunner().invoke(app, [*args, "--body-frame", "/base_link", "--out", str(tmp_path / "named")])
    assert result.exit_code == 0, result.output
    named = Recording.load(tmp_path / "named")
    (_, _, t_a, rpy_a), (_, _, t_b, _) = BASE_ROOF, ROOF_VELODYNE
    R_base_roof = Rotation.from_euler("ZYX", rpy_a[::-1], degrees=True)
    np.testing.assert_allclose(named.extrinsic.lever_arm_m, R_base_roof.apply(t_b) + np.array(t_a), atol=1e-12)
    assert any("from the bag's tf: base_link -> roof -> velodyne" in n for n in named.source["notes"])


def test_broken_tf_chain_is_named_and_the_extrinsic_stays_identity(tmp_path):
    """A ROS 1 bag (frames with tf's leading '/') whose static transforms do not link base_link to velodyne: the
    extrinsic is identity, as without tf, and the notes name both frames and the transforms found."""
    model = synth.sensor(with_offsets=False)
    scans = synth.scans(model, n_scans=2, seed=8)
    t0 = synth.START_UTC - 0.05
    tf = [("/tf_static", t0, [("/base_link", "/roof", *BASE_ROOF[2:]), ("/mount", "/velodyne", *ROOF_VELODYNE[2:])])]
    bag = _write(tmp_path / "drive.bag", "rosbag1", scans, VELODYNE, model, "odometry", tf=tf, frame="/velodyne")
    recording = import_pointcloud2(bag, tmp_path / "rec", quiet=True)
    assert recording.extrinsic.lever_arm_m == (0.0, 0.0, 0.0) and recording.extrinsic.boresight_deg == (0.0, 0.0, 0.0)
    note = next(n for n in recording.source["notes"] if "extrinsic" in n)
    assert "identity" in note and "does not link base_link" in note and "to velodyne" in note, note
    assert "transforms found: base_link -> roof, mount -> velodyne" in note, note


def test_scans_are_sorted_within_one_scan_and_refused_beyond(tmp_path):
    """Messages logged out of their stamps' order: two neighbours swapped come out sorted by time (the raw values as
    in order); a scan logged after two later ones is refused, naming the bag and the time field."""
    model = synth.sensor(with_offsets=False)
    scans = synth.scans(model, n_scans=4, seed=9)
    stamps = [scan["stamp"] for scan in scans]
    swapped = _write(tmp_path / "swapped.bag", "rosbag1", scans, VELODYNE, model, "navsat",
                     logged=[stamps[1] + 0.001, stamps[1], stamps[2], stamps[3]])  # scan 1, 0, 2, 3
    recording = import_pointcloud2(swapped, tmp_path / "rec", quiet=True)
    _check(recording, scans, model, fibre_known=False)
    assert np.all(np.diff(recording.points.read(["time"])["time"]) >= 0)
    late = _write(tmp_path / "late.bag", "rosbag1", scans, VELODYNE, model, "navsat",
                  logged=[stamps[2] + 0.001, stamps[1], stamps[2], stamps[3]])  # scan 1, 2, 0, 3
    with pytest.raises(RecordingError, match=r"late.bag, field 'time': .* before .*scans in time order"):
        import_pointcloud2(late, tmp_path / "late", quiet=True)
    assert not (tmp_path / "late").exists()
