"""sensor_msgs/PointCloud2 scans in a ROS bag (rosbag1, rosbag2 sqlite3 or mcap, MCAP file) -> a recording.

What is read: every PointCloud2 message of one topic (the only one, or `topic`), each one scan,
its fields decoded by their PointField offsets and types (organised or not, either byte order):
x, y, z, intensity, ring and per-point time as point_fields describes (the velodyne_pointcloud
XYZIRT and ouster-ros layouts among them); relative times count from the message's header stamp.
Raw range and encoder azimuth come back through the nominal model (scan_recording, beam_fit).
The trajectory: a file (SBET or trajectory.csv, GPS seconds of week) or the bag's own
NavSatFix + Imu or Odometry messages (ros_trajectory). Header stamps are read as UTC.
The lidar -> body extrinsic: as given, else T_body_lidar from the bag's tf (ros_tf; body = the
trajectory's body frame, lidar = the first cloud's header.frame_id), else identity.
Messages are read one at a time and their returns written as they come (scan_recording).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from graphcal.common.errors import RecordingError
from graphcal.importers.point_fields import ScanPoints, scan_points
from graphcal.importers.ros_messages import RosBag, Topic, open_bag
from graphcal.importers.ros_tf import bag_extrinsic, header_frame
from graphcal.importers.ros_trajectory import bag_trajectory, stamp_s
from graphcal.importers.scan_recording import ScanSource, local_crs, write_scan_recording
from graphcal.importers.velodyne_calibration import VelodyneCalibration
from graphcal.recording.directory import Recording
from graphcal.recording.extrinsic import Extrinsic
from graphcal.recording.trajectory import Trajectory

POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
# sensor_msgs/PointField datatypes -> numpy kinds
_DATATYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}


def cloud_fields(msg, source, index: int = 0) -> np.ndarray:
    """A PointCloud2 message -> a structured array, one column per PointField (COUNT > 1 as sub-arrays)."""
    order = ">" if msg.is_bigendian else "<"
    names, formats, offsets = [], [], []
    for field in msg.fields:
        if field.datatype not in _DATATYPES:
            raise RecordingError(source, f"message {index}: field {field.name!r} of datatype {field.datatype}",
                                 field=field.name, expected="a sensor_msgs/PointField datatype 1..8")
        names.append(field.name)
        formats.append((order + _DATATYPES[field.datatype], (field.count,)) if field.count > 1
                       else order + _DATATYPES[field.datatype])
        offsets.append(field.offset)
    try:
        dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": msg.point_step})
    except ValueError as error:
        raise RecordingError(source, f"message {index}: fields do not fit in point_step {msg.point_step}: {error}",
                             field="fields", expected="PointField offsets within the point") from None
    data = np.asarray(msg.data, dtype=np.uint8)
    need = msg.height * msg.row_step
    if msg.row_step < msg.width * msg.point_step or len(data) < need:
        raise RecordingError(source, f"message {index}: {len(data)} data bytes for {msg.height} rows of "
                                     f"{msg.row_step} bytes", field="data",
                             expected=f"{msg.width} points of {msg.point_step} bytes per row")
    rows = data[:need].reshape(msg.height, msg.row_step)[:, :msg.width * msg.point_step]
    return np.frombuffer(np.ascontiguousarray(rows).tobytes(), dtype=dtype)


def cloud_topic(bag: RosBag, topic: str | None = None) -> Topic:
    """The bag's PointCloud2 topic: the only one, or the one named `topic`; RecordingError otherwise."""
    clouds = bag.of_type(POINTCLOUD2, topic)
    if len(clouds) != 1:
        raise RecordingError(bag.path, f"{len(clouds)} {POINTCLOUD2} topics{f' named {topic}' if topic else ''}; "
                                       f"topics: {bag.listing()}", field="topic",
                             expected="one PointCloud2 topic (choose it with --topic)" if clouds else
                             "a PointCloud2 topic (a lidar driver's point cloud)")
    return clouds[0]


def read_scans(bag: RosBag, cloud: Topic) -> Iterator[ScanPoints]:
    """The scans of the PointCloud2 topic, one message at a time, in the bag's order."""
    for index, (_, _, msg) in enumerate(bag.messages([cloud])):
        source = f"{bag.path}, {cloud.name} message {index}"
        yield scan_points(cloud_fields(msg, bag.path, index), source, stamp_s(msg.header), "the header stamp")


def import_pointcloud2(bag: str | Path, out: str | Path, *, topic: str | None = None,
                       calibration: VelodyneCalibration | None = None, trajectory: Trajectory | None = None,
                       crs: str = "auto", pose_topic: str | None = None, extrinsic: Extrinsic | None = None,
                       origin: tuple[float, float] = (0.0, 0.0), model: str = "lidar", name: str | None = None,
                       body_frame: str | None = None, quiet: bool = False) -> Recording:
    """A bag's PointCloud2 scans as the recording folder `out` (written whole, message by message; an existing
    folder is replaced). trajectory: GPS seconds of week (SBET, CSV) in the world CRS `crs`, else from the bag.
    extrinsic: lidar -> body (the trajectory's frame); when not given, from the bag's tf (T_body_frame_lidar, body_frame
    by default the frame of the bag's trajectory: give it with a trajectory file), else identity."""
    bag = Path(bag)
    with open_bag(bag) as opened:
        cloud = cloud_topic(opened, topic)
        notes = [f"scans: {cloud.name} (PointCloud2, one message per scan, header stamps read as UTC)"]
        if trajectory is None:
            from_bag = bag_trajectory(opened, pose_topic)
            trajectory, crs = from_bag.trajectory, "auto"
            body_frame = body_frame or from_bag.body_frame
            notes.extend(from_bag.notes)
            if not trajectory.geodetic:
                crs = local_crs(*origin)
                notes.append(f"the odometry frame is taken as a local frame (x east, y north, z up) centred at lat "
                             f"{origin[0]:g}, lon {origin[1]:g}: a transverse Mercator CRS")
            utc = True
        else:
            notes.append("trajectory: the file given (GPS seconds of week)")
            utc = False
        extrinsic, extrinsic_note = bag_extrinsic(opened, extrinsic, body_frame, header_frame(opened, [cloud]),
                                                  "the clouds' header.frame_id")
        notes += ["points taken as the driver wrote them, in the sensor frame (not transformed to another frame); raw "
                  "range and azimuth are recovered through the nominal model (exact only when it is the driver's own)",
                  extrinsic_note]
        source = ScanSource(path=bag, importer="pointcloud2", model=model, trajectory=trajectory,
                            trajectory_utc=utc, extrinsic=extrinsic, crs=crs, notes=notes)
        return write_scan_recording(read_scans(opened, cloud), source, out, calibration, name or bag.stem, quiet)
