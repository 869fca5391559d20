"""The lidar -> body extrinsic from a ROS bag's transforms (tf2_msgs/TFMessage on /tf_static, and /tf).

A geometry_msgs/TransformStamped with header.frame_id a and child_frame_id b is T_a_b: it maps
coordinates in frame b into frame a, p_a = R_a_b p_b + t_a_b (translation in m along a's axes,
rotation a quaternion x, y, z, w), graphcal's convention (docs/concepts.md). The transforms form a
tree, one parent per frame; T_body_lidar is the product of the transforms along the path from the
body frame to the lidar frame (up to their nearest common ancestor and down, inverting the
transforms climbed), e.g. T_base_link_velodyne = T_base_link_roof T_roof_velodyne.

Read: every transform of a topic whose name ends in tf_static (the last one per child frame), and
every transform of the other TFMessage topics (/tf) that stays the same over the bag within 1 µm
and 1 µrad (a mounting published on /tf); the ones that move (odom -> base_link) are left out.
Frame names are compared without a leading '/', as tf2 does (ROS 1 bags often have one).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from graphcal.common.errors import RecordingError
from graphcal.importers.ros_messages import RosBag, Topic
from graphcal.recording.extrinsic import Extrinsic
from graphcal.recording.rotations import rpy_deg_from_rotation

TFMESSAGE = "tf2_msgs/msg/TFMessage"
_FIXED_M, _FIXED_RAD = 1e-6, 1e-6  # a /tf transform that moves less than this over the bag is a mounting


@dataclass(frozen=True)
class Transform:
    """T_parent_child: p_parent = rotation.apply(p_child) + translation_m [m, parent axes]."""

    parent: str
    child: str
    rotation: Rotation
    translation_m: np.ndarray

    @classmethod
    def identity(cls, frame: str) -> Transform:
        return cls(frame, frame, Rotation.identity(), np.zeros(3))

    def then(self, other: Transform) -> Transform:
        """T_a_c = T_a_b T_b_c (self T_a_b, other T_b_c)."""
        return Transform(self.parent, other.child, self.rotation * other.rotation,
                         self.rotation.apply(other.translation_m) + self.translation_m)

    def inverse(self) -> Transform:
        """T_b_a of T_a_b."""
        rotation = self.rotation.inv()
        return Transform(self.child, self.parent, rotation, -rotation.apply(self.translation_m))

    def same_as(self, other: Transform) -> bool:
        """The same mounting within 1 µm and 1 µrad."""
        return (np.linalg.norm(self.translation_m - other.translation_m) <= _FIXED_M
                and (self.rotation.inv() * other.rotation).magnitude() <= _FIXED_RAD)


@dataclass(frozen=True)
class FrameTree:
    """The bag's fixed transforms by child frame, and the moving ones of /tf: {child: parent}."""

    fixed: dict[str, Transform]
    moving: dict[str, str]

    def link(self, body_frame: str, lidar_frame: str) -> tuple[Transform, list[str]] | None:
        """T_body_lidar through the tree and the frames on the way (up to the nearest common ancestor and down);
        None when the tree does not link the two frames."""
        from_body, from_lidar = self._to_ancestors(body_frame), self._to_ancestors(lidar_frame)
        common = next((frame for frame in from_lidar if frame in from_body), None)
        if common is None:
            return None
        up, down = list(from_body), list(from_lidar)
        frames = up[:up.index(common) + 1] + down[:down.index(common)][::-1]
        return from_body[common].inverse().then(from_lidar[common]), frames

    def listing(self) -> str:
        """The transforms found, in plain words."""
        fixed = [f"{t.parent} -> {t.child}" for t in sorted(self.fixed.values(), key=lambda t: (t.parent, t.child))]
        moving = [f"{parent} -> {child} (moving, left out)" for child, parent in sorted(self.moving.items())]
        return ", ".join(fixed + moving) or "none"

    def _to_ancestors(self, frame: str) -> dict[str, Transform]:
        """T_a_frame for frame itself (identity) and each of its ancestors a, from frame upwards."""
        poses = {frame: Transform.identity(frame)}
        current = poses[frame]
        while current.parent in self.fixed and self.fixed[current.parent].parent not in poses:
            current = self.fixed[current.parent].then(current)
            poses[current.parent] = current
        return poses


def read_frame_tree(bag: RosBag) -> FrameTree | None:
    """The transforms of the bag's TFMessage topics (see the module docstring); None when it has none."""
    topics = bag.of_type(TFMESSAGE)
    if not topics:
        return None
    static, first, moving = {}, {}, {}
    for topic, _, msg in bag.messages(topics):
        for stamped in msg.transforms:
            transform = _transform(stamped, bag, topic.name)
            if topic.name.endswith("tf_static"):
                static[transform.child] = transform
            elif transform.child not in first:
                first[transform.child] = transform
            elif not first[transform.child].same_as(transform):
                moving[transform.child] = transform.parent
    fixed = {child: t for child, t in first.items() if child not in moving}
    return FrameTree({**fixed, **static}, moving)


def tf_extrinsic(bag: RosBag, body_frame: str | None, lidar_frame: str, lidar_what: str = "the lidar frame"
                 ) -> tuple[Extrinsic | None, str]:
    """T_body_lidar from the bag's transforms as the lidar -> body extrinsic, and a note saying where it came
    from; None (and a note naming the frames found) when the bag has no transforms, no body frame is known
    (body_frame None) or the transforms do not link the body frame to lidar_frame. lidar_what: where the lidar
    frame's name comes from, for the note."""
    if body_frame is None:
        return None, ("the bag's tf is not read: the trajectory's body frame has no name in the bag (give it with "
                      "--body-frame)")
    body_frame = body_frame.lstrip("/")
    tree = read_frame_tree(bag)
    if tree is None:
        return None, f"no {TFMESSAGE} in the bag"
    link = tree.link(body_frame, lidar_frame)
    if link is None:
        return None, (f"the bag's tf does not link {body_frame} (the body frame) to {lidar_frame} ({lidar_what}); "
                      f"transforms found: {tree.listing()}")
    T_body_lidar, frames = link
    extrinsic = Extrinsic(tuple(float(v) for v in T_body_lidar.translation_m),
                          tuple(float(v) for v in rpy_deg_from_rotation(T_body_lidar.rotation)))
    return extrinsic, (f"lidar -> body extrinsic from the bag's tf: {' -> '.join(frames)} "
                       f"composed, lever arm {_rounded(extrinsic.lever_arm_m)} m, boresight "
                       f"{_rounded(extrinsic.boresight_deg)} deg")


def bag_extrinsic(bag: RosBag, given: Extrinsic | None, body_frame: str | None, lidar_frame: str,
                  lidar_what: str = "the lidar frame") -> tuple[Extrinsic, str]:
    """The lidar -> body extrinsic and where it came from: as given (it wins over the bag), else the bag's
    T_body_lidar (tf_extrinsic), else identity (with the reason the bag's tf gave none)."""
    if given is not None:
        return given, "lidar -> body extrinsic as given (the bag's tf is not read)"
    from_tf, note = tf_extrinsic(bag, body_frame, lidar_frame, lidar_what)
    if from_tf is not None:
        return from_tf, note
    return Extrinsic((0.0, 0.0, 0.0), (0.0, 0.0, 0.0)), f"lidar -> body extrinsic: identity (none given; {note})"


def header_frame(bag: RosBag, topics: list[Topic]) -> str:
    """The header.frame_id of the first message of the topics (the frame its data are in), without tf2's
    leading '/'; '' for no message."""
    first = next(iter(bag.messages(topics)), None)
    return "" if first is None else first[2].header.frame_id.lstrip("/")


def _transform(stamped, bag: RosBag, topic: str) -> Transform:
    """A geometry_msgs/TransformStamped as T_parent_child; RecordingError for a non-finite or zero one."""
    parent, child = stamped.header.frame_id.lstrip("/"), stamped.child_frame_id.lstrip("/")
    q, t = stamped.transform.rotation, stamped.transform.translation
    quaternion, translation = np.array([q.x, q.y, q.z, q.w]), np.array([t.x, t.y, t.z])
    if not (np.all(np.isfinite(quaternion)) and np.all(np.isfinite(translation)) and np.linalg.norm(quaternion) > 0):
        raise RecordingError(bag.path, f"{topic}: transform {parent} -> {child} with rotation {quaternion.tolist()}, "
                                       f"translation {translation.tolist()}", field="transform",
                             expected="a finite translation and a non-zero quaternion")
    return Transform(parent, child, Rotation.from_quat(quaternion), translation)


def _rounded(values) -> list[float]:
    return [round(float(v), 6) for v in values]
