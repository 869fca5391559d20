"""ROS messages of a bag, whatever its container: rosbag1 (.bag), rosbag2 (a folder with metadata.yaml,
sqlite3 or mcap storage) or a standalone storage file (.mcap, .db3), read with rosbags' AnyReader.

Message definitions come from the bag when it carries them, else from the ROS 2 Humble type
store. Message types are named the ROS 2 way (`sensor_msgs/msg/PointCloud2`) in every case; the
messages are rosbags' dataclasses.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from graphcal.common.errors import ConfigError, GraphcalError, RecordingError


@dataclass(frozen=True)
class Topic:
    """A topic of the bag: its name and message type (ROS 2 spelling)."""

    name: str
    msgtype: str


def msgtype_name(msgtype: str) -> str:
    """'sensor_msgs/PointCloud2' (ROS 1) or 'sensor_msgs/msg/PointCloud2' -> 'sensor_msgs/msg/PointCloud2'."""
    package, _, name = msgtype.rpartition("/")
    return msgtype if package.endswith("/msg") else f"{package}/msg/{name}"


class RosBag:
    """An open bag: its topics, and its messages of some topics in log-time order."""

    def __init__(self, path: Path, topics: list[Topic], messages):
        self.path, self.topics, self._messages = path, topics, messages

    def messages(self, topics: list[Topic]) -> Iterator[tuple[Topic, int, object]]:
        """(topic, log time ns, deserialised message) of the given topics."""
        yield from self._messages(topics)

    def of_type(self, msgtype: str, topic: str | None = None) -> list[Topic]:
        return [t for t in self.topics if t.msgtype == msgtype and (topic is None or t.name == topic)]

    def listing(self) -> str:
        return ", ".join(sorted(f"{t.name} ({t.msgtype})" for t in self.topics)) or "none"


BAG_EXPECTED = "a rosbag1 file, a rosbag2 folder with its metadata.yaml, or an MCAP or db3 file"


def check_bag_path(path: Path) -> None:
    """RecordingError naming path when it cannot be a bag: absent, or a folder without a rosbag2 metadata.yaml."""
    if not path.exists():
        raise RecordingError(path, "bag not found")
    if path.is_dir() and not (path / "metadata.yaml").is_file():
        raise RecordingError(path, "a folder without metadata.yaml: not a rosbag2 recording", expected=BAG_EXPECTED)


@contextmanager
def open_bag(path: str | Path) -> Iterator[RosBag]:
    """Open a bag of any container (see the module docstring); RecordingError for an unreadable one."""
    path = Path(path)
    check_bag_path(path)
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise ConfigError('reading ROS bags needs rosbags: pip install "graphcal[rosbag]"') from None
    try:
        with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
            yield ros_bag(path, reader.connections, lambda chosen: reader.messages(connections=chosen),
                          reader.deserialize)
    except GraphcalError:
        raise
    except Exception as error:  # rosbags' own (no metadata.yaml, a damaged file, a cut message)
        raise RecordingError(path, f"not a readable ROS bag: {type(error).__name__}: {error}",
                             expected=BAG_EXPECTED) from None


def ros_bag(path: Path, connections: list, messages, deserialize) -> RosBag:
    """A RosBag of an open reader's connections (rosbags Connection), messages(connections) -> iterator of
    (connection, log time ns, raw bytes) in log-time order, and deserialize(raw, msgtype)."""
    def topic_of(connection) -> Topic:
        return Topic(connection.topic, msgtype_name(connection.msgtype))

    def read(topics: list[Topic]):
        wanted = set(topics)
        chosen = [c for c in connections if topic_of(c) in wanted]
        if not chosen:  # rosbags reads every connection when given none
            return
        for connection, log_ns, raw in messages(chosen):
            yield topic_of(connection), log_ns, deserialize(raw, connection.msgtype)

    return RosBag(path, list(dict.fromkeys(topic_of(c) for c in connections)), read)
