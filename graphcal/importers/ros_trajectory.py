"""A trajectory from the messages of a ROS bag: sensor_msgs/NavSatFix with sensor_msgs/Imu, or nav_msgs/Odometry.

- NavSatFix + Imu: position = the fixes (WGS84 latitude, longitude deg; altitude m above the
  ellipsoid, as the message defines it), attitude = the IMU orientation SLERPed at each fix. The
  orientation is read as REP 103/145 ask: the body frame x forward, y left, z up relative to
  East-North-Up, which is the recording's convention (yaw counter-clockwise from east). Fixes
  with status < 0 (no fix) are left out. A geodetic trajectory (crs auto).
- Odometry: pose.pose of child_frame_id in frame_id (position m, orientation quaternion), a
  local metric frame (the importer places it as a projected CRS).
Times are the header stamps, s since 1970 (UTC as the bag's clock has it). The body frame, by its
name in the bag's tf: Odometry's child_frame_id, or the Imu's header.frame_id (the frame whose
attitude the trajectory carries); none when the messages name several.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from graphcal.common.errors import RecordingError
from graphcal.importers.ros_messages import RosBag, Topic
from graphcal.recording.rotations import rpy_deg_from_rotation, unwrap_deg
from graphcal.recording.trajectory import Trajectory

NAVSATFIX = "sensor_msgs/msg/NavSatFix"
IMU = "sensor_msgs/msg/Imu"
ODOMETRY = "nav_msgs/msg/Odometry"


def stamp_s(header) -> float:
    """A std_msgs/Header stamp as s since 1970."""
    return header.stamp.sec + 1e-9 * header.stamp.nanosec


@dataclass(frozen=True)
class BagTrajectory:
    """The trajectory (body -> world, times in UTC s since 1970), what was read, and the body frame's name
    in the bag (None when the messages name several)."""

    trajectory: Trajectory
    notes: list[str]
    body_frame: str | None


def bag_trajectory(bag: RosBag, topic: str | None = None) -> BagTrajectory:
    """The bag's trajectory (NavSatFix + Imu preferred, else Odometry; `topic` picks a NavSatFix or Odometry
    topic); RecordingError when the bag has neither."""
    fixes, imus, odometry = _trajectory_topics(bag, topic)
    if fixes and imus:
        return _navsat(bag, fixes[0], imus[0])
    if odometry:
        return _odometry(bag, odometry[0])
    raise RecordingError(bag.path, f"no trajectory: no {NAVSATFIX} with {IMU}, no {ODOMETRY}"
                                   f"{f' on topic {topic}' if topic else ''}; topics: {bag.listing()}",
                         expected="GNSS/INS messages in the bag, or a trajectory file (--trajectory)")


def trajectory_frame(bag: RosBag, topic: str | None = None) -> str | None:
    """The body frame of the trajectory bag_trajectory would read (the Imu's header.frame_id with NavSatFix, else
    Odometry's child_frame_id), read from those messages alone; None when the bag has neither or they name
    several frames."""
    fixes, imus, odometry = _trajectory_topics(bag, topic)
    if fixes and imus:
        return _one_frame({msg.header.frame_id for _, _, msg in bag.messages(imus[:1])})
    if odometry:
        return _one_frame({msg.child_frame_id for _, _, msg in bag.messages(odometry[:1])})
    return None


def _trajectory_topics(bag: RosBag, topic: str | None) -> tuple[list[Topic], list[Topic], list[Topic]]:
    """The bag's NavSatFix, Imu and Odometry topics (`topic` picks a NavSatFix or Odometry topic)."""
    return bag.of_type(NAVSATFIX, topic), bag.of_type(IMU), bag.of_type(ODOMETRY, topic)


def _navsat(bag: RosBag, fix_topic: Topic, imu_topic: Topic) -> BagTrajectory:
    fixes, imu, imu_frames = [], [], set()
    for topic, _, msg in bag.messages([fix_topic, imu_topic]):
        if topic == fix_topic:
            if msg.status.status >= 0:
                fixes.append((stamp_s(msg.header), msg.latitude, msg.longitude, msg.altitude))
        else:
            q = msg.orientation
            imu.append((stamp_s(msg.header), q.x, q.y, q.z, q.w))
            imu_frames.add(msg.header.frame_id)
    fixes, imu = _increasing(np.array(fixes).reshape(-1, 4)), _increasing(np.array(imu).reshape(-1, 5))
    if len(fixes) < 2 or len(imu) < 2:
        raise RecordingError(bag.path, f"{len(fixes)} valid fixes on {fix_topic.name}, {len(imu)} IMU messages on "
                                       f"{imu_topic.name}", expected="at least 2 of each")
    inside = (fixes[:, 0] >= imu[0, 0]) & (fixes[:, 0] <= imu[-1, 0])
    fixes = fixes[inside]
    if len(fixes) < 2:
        raise RecordingError(bag.path, f"the fixes of {fix_topic.name} and the IMU messages of {imu_topic.name} do "
                                       "not overlap in time", expected="GNSS fixes within the IMU's time span")
    rotation = Slerp(imu[:, 0], Rotation.from_quat(imu[:, 1:5]))(fixes[:, 0])
    trajectory = Trajectory(fixes[:, 0], fixes[:, 1:4].copy(), _rpy(rotation), geodetic=True)
    trajectory.validate(bag.path)
    notes = [f"trajectory: {len(fixes)} fixes of {fix_topic.name} (NavSatFix, altitude above the ellipsoid), attitude "
             f"from {imu_topic.name} (Imu orientation read as REP 103: x forward, y left, z up vs East-North-Up); "
             "the fixes are taken as the positions of the Imu's frame: a GNSS antenna's offset from it is not applied"]
    return BagTrajectory(trajectory, notes, _one_frame(imu_frames))


def _odometry(bag: RosBag, topic: Topic) -> BagTrajectory:
    rows, frames = [], set()
    for _, _, msg in bag.messages([topic]):
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        rows.append((stamp_s(msg.header), p.x, p.y, p.z, q.x, q.y, q.z, q.w))
        frames.add((msg.header.frame_id, msg.child_frame_id))
    rows = _increasing(np.array(rows).reshape(-1, 8))
    if len(rows) < 2:
        raise RecordingError(bag.path, f"{len(rows)} Odometry messages on {topic.name}", expected="at least 2")
    trajectory = Trajectory(rows[:, 0], rows[:, 1:4].copy(), _rpy(Rotation.from_quat(rows[:, 4:8])), geodetic=False)
    trajectory.validate(bag.path)
    names = ", ".join(f"{child or '?'} in {parent or '?'}" for parent, child in sorted(frames))
    notes = [f"trajectory: {len(rows)} poses of {topic.name} (Odometry: {names}), a local frame"]
    return BagTrajectory(trajectory, notes, _one_frame({child for _, child in frames}))


def _one_frame(frames: set[str]) -> str | None:
    """The frame the messages name (without tf2's leading '/'), None when they name several."""
    names = {frame.lstrip("/") for frame in frames}
    return names.pop() if len(names) == 1 else None


def _rpy(rotation: Rotation) -> np.ndarray:
    rpy = rpy_deg_from_rotation(rotation)
    rpy[:, 2] = unwrap_deg(rpy[:, 2])
    return rpy


def _increasing(rows: np.ndarray) -> np.ndarray:
    """Rows sorted by their first column (time), repeated times dropped."""
    rows = rows[np.argsort(rows[:, 0], kind="stable")]
    return rows[np.concatenate([[True], np.diff(rows[:, 0]) > 0])] if len(rows) else rows
