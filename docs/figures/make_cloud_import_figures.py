"""docs/figures/import_{pcd,pointcloud2,las}.png: the real clouds of the import how-tos, imported and drawn back.

- import_pcd.png: the OpenCalib sample (5 binary_compressed PCD scans, poses in a local ENU frame),
  `graphcal import pcd`; world points from the recording, top view coloured by fibre, and the
  fitted elevation per fibre.
- import_pointcloud2.png: nebula's decoded VLP-16 scan (real points, with channel and time_stamp)
  published as one sensor_msgs/PointCloud2 message in a rosbag2 bag with a still Odometry, then
  `graphcal import pointcloud2 --calibration VLP16.yaml`; top view by fibre, and the recovered range
  against nebula's own distance field (each return matched to nebula's point by position).
- import_las.png: the leeward airborne LAS with its SBET, `graphcal import las`; top view of the
  points georeferenced back from the recording, and range against the scan angle (azimuth).

    .venv/bin/python docs/figures/make_cloud_import_figures.py [SHARED_REAL_DATA_FOLDER]

Matplotlib (Agg), deterministic.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from scipy.spatial import cKDTree  # noqa: E402

from graphcal.importers.las_cloud import import_las  # noqa: E402
from graphcal.importers.pcd import read_pcd  # noqa: E402
from graphcal.importers.pcd_folder import import_pcd_folder  # noqa: E402
from graphcal.importers.pointcloud2 import import_pointcloud2  # noqa: E402
from graphcal.importers.sbet import import_sbet  # noqa: E402
from graphcal.importers.velodyne_calibration import read_velodyne_calibration  # noqa: E402
from graphcal.recording.georeference import georeference  # noqa: E402

HERE = Path(__file__).resolve().parent
DEFAULT = HERE.parents[2] / "shared/data/real"


def _world(recording, rows=None) -> tuple[np.ndarray, dict]:
    points = recording.points.read()
    if rows is not None:
        points = {key: values[rows] for key, values in points.items()}
    xyz = georeference(points["time"], points["fibre"], points["range"].astype(np.float64),
                       points["azimuth"].astype(np.float64), recording.sensor, recording.extrinsic,
                       recording.world.poses)
    return xyz, points


def _top(ax, xyz, colour, label, extent=None, equal=True):
    centre = np.median(xyz[:, :2], axis=0)
    shown = ax.scatter(xyz[:, 0] - centre[0], xyz[:, 1] - centre[1], c=colour, s=0.3 if equal else 2, cmap="viridis",
                       linewidths=0)
    if equal:
        ax.set_aspect("equal")
    if extent:
        ax.set_xlim(-extent, extent)
        ax.set_ylim(-extent, extent)
    ax.set_xlabel("east [m] (from the median point)")
    ax.set_ylabel("north [m]")
    plt.colorbar(shown, ax=ax, label=label, shrink=0.8)


def _side(fig, side, x, y, labels: tuple[str, str, str], path: Path, style: str = ".", size: float = 2) -> Path:
    """The right panel (y against x, labels: x label, y label, title), then the figure written to path."""
    side.plot(x, y, style, ms=size)
    side.set_xlabel(labels[0])
    side.set_ylabel(labels[1])
    side.set_title(labels[2])
    side.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return path


def pcd_figure(real: Path, out: Path) -> Path:
    folder = real / "pjlab_lidar2imu_pcd_poses"
    with tempfile.TemporaryDirectory() as tmp:
        recording = import_pcd_folder(folder / "top_center_lidar", folder / "top_center_lidar-enu.txt",
                                      Path(tmp) / "pcd", quiet=True)
        rows = np.arange(0, len(recording.points), 4)
        xyz, points = _world(recording, rows)
    fig, (top, side) = plt.subplots(1, 2, figsize=(12, 5.2), gridspec_kw={"width_ratios": [1.4, 1]})
    _top(top, xyz, points["fibre"], "fibre (ring)", extent=60)
    top.set_title(f"OpenCalib sample, imported: {len(recording.points):,} returns, 4 scans (every 4th drawn)")
    return _side(fig, side, np.arange(recording.sensor.n_fibres), recording.sensor.elevation_deg,
                 ("fibre (= ring id)", "fitted elevation [deg]", "nominal model fitted per ring (misfit 0.1 mm median)"),
                 out / "import_pcd.png", "o", 3)


def _nebula_bag(real: Path, bag: Path) -> np.ndarray:
    """nebula's VLP-16 scan as a PointCloud2 message (its own fields and layout) in a rosbag2 with a still Odometry;
    returns the scan's points."""
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    _, points = read_pcd(real / "nebula_velodyne_rosbag2/vlp16/1673400472138016708.pcd")
    store, types = get_typestore(Stores.ROS2_HUMBLE), get_typestore(Stores.ROS2_HUMBLE).types
    stamp_ns = 1673400472138016708
    datatypes = {"f4": 7, "u1": 2, "u2": 4, "u4": 6}
    fields = [types["sensor_msgs/msg/PointField"](name=name, offset=points.dtype.fields[name][1],
                                                  datatype=datatypes[points.dtype[name].str[1:]], count=1)
              for name in points.dtype.names]

    def header(ns):
        return types["std_msgs/msg/Header"](stamp=types["builtin_interfaces/msg/Time"](sec=ns // 10**9,
                                                                                      nanosec=ns % 10**9),
                                            frame_id="velodyne")
    cloud = types["sensor_msgs/msg/PointCloud2"](header=header(stamp_ns), height=1, width=len(points), fields=fields,
                                                 is_bigendian=False, point_step=points.dtype.itemsize,
                                                 row_step=points.dtype.itemsize * len(points),
                                                 data=np.frombuffer(points.tobytes(), np.uint8), is_dense=True)
    vector = types["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    with Writer(bag, version=9) as writer:
        lidar = writer.add_connection("/points", "sensor_msgs/msg/PointCloud2", typestore=store)
        odom = writer.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=store)
        writer.write(lidar, stamp_ns, store.serialize_cdr(cloud, "sensor_msgs/msg/PointCloud2"))
        for ns in (stamp_ns - 10**8, stamp_ns + 2 * 10**8):
            pose = types["geometry_msgs/msg/Pose"](position=types["geometry_msgs/msg/Point"](x=0.0, y=0.0, z=0.0),
                                                   orientation=types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0,
                                                                                                    z=0.0, w=1.0))
            msg = types["nav_msgs/msg/Odometry"](
                header=header(ns), child_frame_id="velodyne",
                pose=types["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
                twist=types["geometry_msgs/msg/TwistWithCovariance"](
                    twist=types["geometry_msgs/msg/Twist"](linear=vector, angular=vector), covariance=np.zeros(36)))
            writer.write(odom, ns, store.serialize_cdr(msg, "nav_msgs/msg/Odometry"))
    return points


def pointcloud2_figure(real: Path, out: Path) -> Path:
    with tempfile.TemporaryDirectory() as tmp:
        points = _nebula_bag(real, Path(tmp) / "vlp16")
        calibration = read_velodyne_calibration(real / "nebula_velodyne_rosbag2/calibration/VLP16.yaml")
        recording = import_pointcloud2(Path(tmp) / "vlp16", Path(tmp) / "recording", calibration=calibration,
                                       quiet=True)
        xyz, imported = _world(recording)
    echo = points[np.any(np.column_stack([points[n] for n in "xyz"]) != 0, axis=1)]
    p_lidar = recording.sensor.to_xyz(imported["fibre"].astype(np.intp), imported["range"].astype(np.float64),
                                      imported["azimuth"].astype(np.float64))
    order = cKDTree(np.column_stack([echo[n] for n in "xyz"]).astype(np.float64)).query(p_lidar)[1]
    fig, (top, side) = plt.subplots(1, 2, figsize=(12, 5.2), gridspec_kw={"width_ratios": [1.4, 1]})
    _top(top, xyz, imported["fibre"], "fibre (laser id)", extent=12)
    top.set_title(f"nebula VLP-16 scan as PointCloud2, imported: {len(xyz):,} returns")
    difference = 1000 * (imported["range"] - echo["distance"][order])
    side.set_ylim(-0.01, 0.01)
    return _side(fig, side, echo["distance"][order], difference,
                 ("nebula's distance field [m]", "recovered range - nebula's distance [mm]",
                  f"raw range through VLP16.yaml: max |diff| {np.abs(difference).max():.4f} mm"),
                 out / "import_pointcloud2.png", size=1)


def las_figure(real: Path, out: Path) -> Path:
    folder = real / "leeward_airborne_las_sbet"
    with tempfile.TemporaryDirectory() as tmp:
        recording = import_las(folder / "points.las", import_sbet(folder / "sbet.out"), Path(tmp) / "leeward")
        xyz, points = _world(recording)
    fig, (top, side) = plt.subplots(1, 2, figsize=(12, 5.2), gridspec_kw={"width_ratios": [1.4, 1]})
    _top(top, xyz, points["time"] - points["time"][0], "time [s]", equal=False)
    top.set_title(f"leeward airborne LAS + SBET, imported: {len(xyz):,} returns")
    return _side(fig, side, np.degrees(points["azimuth"]), points["range"],
                 ("azimuth about the fitted scanner axis [deg]", "recovered range [m]", "one beam: range across the swath"),
                 out / "import_las.png")


if __name__ == "__main__":
    real = Path(sys.argv[1]) if len(sys.argv) > 1 else DEFAULT
    for make in (pcd_figure, pointcloud2_figure, las_figure):
        print(make(real, HERE))
