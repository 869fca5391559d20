"""Velodyne packets in a ROS bag (velodyne_msgs/VelodyneScan, ROS 1 or ROS 2) -> a recording.

The bag is read with rosbags (optional: `pip install "graphcal[rosbag]"`), also an early ROS 2
bag whose metadata leaves the serialization format empty (read as CDR); the 1206-byte
packets, in the order of their ROS stamps, go through the same survey and chunk decoder as pcap captures
(velodyne_recording), and the packets' ROS stamps stand for the capture host clock (the hour of the sensor
timestamps). The bag is read message by message, twice, when its packets are in stamp order (as a driver records
them); a bag with packets out of that order is held in memory and sorted (a tenth of its returns). The returns are
written as they are decoded. A bag carries no $GPRMC: give a position or a trajectory. docs/howto/import.md has
the details.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path

import numpy as np

from graphcal.common.errors import ConfigError, GraphcalError, RecordingError
from graphcal.common.progress import progress
from graphcal.common.yamlfile import read_yaml
from graphcal.importers.ros_messages import BAG_EXPECTED, RosBag, Topic, check_bag_path, ros_bag
from graphcal.importers.ros_tf import bag_extrinsic, header_frame
from graphcal.importers.ros_trajectory import trajectory_frame
from graphcal.importers.velodyne_calibration import VelodyneCalibration
from graphcal.importers.velodyne_packets import PACKET, PACKET_BYTES
from graphcal.importers.velodyne_recording import (
    SurveyedCapture,
    VelodyneReturns,
    decoded_capture,
    surveyed_capture,
    write_velodyne_recording,
)
from graphcal.importers.velodyne_survey import PacketSurvey
from graphcal.recording.directory import Recording
from graphcal.recording.extrinsic import Extrinsic

SCAN_TYPE = "velodyne_msgs/msg/VelodyneScan"
CHUNK_PACKETS = 1024  # packets read and decoded at a time, in whole messages (about 0.35 M returns)
# ROS 2 bags do not carry message definitions: velodyne_msgs' own
_DEFINITIONS = {"velodyne_msgs/msg/VelodynePacket": "builtin_interfaces/Time stamp\nuint8[1206] data",
                SCAN_TYPE: "std_msgs/Header header\nvelodyne_msgs/VelodynePacket[] packets"}


def read_velodyne_packets(bag: str | Path, topic: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(packets as a PACKET array, their ROS stamps in s since 1970) of the VelodyneScan messages, all at once."""
    chunks = list(packet_chunks(bag, topic))
    return np.concatenate([packets for packets, _, _ in chunks]), np.concatenate([stamps for _, stamps, _ in chunks])


def packet_chunks(bag: str | Path, topic: str | None = None) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The packets of the VelodyneScan messages in the bag's order, whole messages of about CHUNK_PACKETS packets at a
    time: (PACKET array, ROS stamps [s since 1970], index of each packet in the bag). RecordingError naming the bag
    when it has none."""
    bag = Path(bag)
    data, stamps, before = [], [], 0
    with velodyne_bag(bag) as opened:
        for scans_topic, _, msg in opened.messages(scan_topics(opened, topic)):
            for packet in msg.packets:
                if len(packet.data) != PACKET_BYTES:
                    raise RecordingError(bag, f"packet of {len(packet.data)} bytes on {scans_topic.name}",
                                         expected=f"{PACKET_BYTES}-byte Velodyne data packets")
                data.append(np.asarray(packet.data, dtype=np.uint8))
                stamps.append(packet.stamp.sec + 1e-9 * packet.stamp.nanosec)
            if len(data) >= CHUNK_PACKETS:
                yield _chunk(data, stamps, before)
                data, stamps, before = [], [], before + len(data)
    if data:
        yield _chunk(data, stamps, before)
    elif not before:
        raise RecordingError(bag, "no packet in the VelodyneScan messages", expected="Velodyne data packets")


def scan_topics(bag: RosBag, topic: str | None = None) -> list[Topic]:
    """The bag's VelodyneScan topics (every one, or the one named `topic`); RecordingError when there is none."""
    scans = bag.of_type(SCAN_TYPE, topic)
    if not scans:
        raise RecordingError(bag.path, f"no {SCAN_TYPE} topic{f' named {topic}' if topic else ''}; topics: "
                                       f"{bag.listing()}", field="topic",
                             expected="Velodyne packets (velodyne_driver output)")
    return scans


@contextmanager
def velodyne_bag(bag: Path) -> Iterator[RosBag]:
    """A bag opened with velodyne_msgs' types known (ROS 2 bags do not carry message definitions); RecordingError
    naming it when rosbags cannot read it."""
    try:
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    except ImportError:
        raise ConfigError('reading ROS bags needs rosbags: pip install "graphcal[rosbag]"') from None
    check_bag_path(bag)
    store = get_typestore(Stores.ROS2_HUMBLE)
    for name, definition in _DEFINITIONS.items():
        store.register(get_types_from_msg(definition, name))
    try:
        with _open_bag(bag, store) as (connections, messages, deserialize):
            yield ros_bag(bag, connections, messages, deserialize)
    except GraphcalError:
        raise
    except Exception as error:  # rosbags' own (a folder without metadata.yaml, an empty or damaged bag, a cut message)
        raise RecordingError(bag, f"not a readable ROS bag: {type(error).__name__}: {error}",
                             expected=BAG_EXPECTED) from None


def _chunk(data: list[np.ndarray], stamps: list[float], before: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(PACKET array, stamps, indices in the bag) of packets read after `before` others."""
    return np.stack(data).view(PACKET).ravel(), np.asarray(stamps), before + np.arange(len(data))


@contextmanager
def _open_bag(bag: Path, store) -> Iterator[tuple[list, Callable, Callable]]:
    """(connections, messages(connections) -> iterator of (connection, log time ns, raw bytes),
    deserialize(raw, msgtype)) of a bag: rosbags' AnyReader, or for a rosbag2 sqlite3 folder whose
    metadata.yaml leaves the serialization format empty (early ROS 2 recorders), its storage files
    read as CDR, the only format rosbag2 records."""
    if not _unnamed_cdr(bag):
        from rosbags.highlevel import AnyReader

        with AnyReader([bag], default_typestore=store) as reader:
            yield reader.connections, lambda wanted: reader.messages(connections=wanted), reader.deserialize
        return
    from rosbags.rosbag2.storage_sqlite3 import Sqlite3Reader

    with ExitStack() as stack:
        storages = []
        for path in sorted(bag.glob("*.db3")):
            storages.append(Sqlite3Reader(path))
            storages[-1].open()
            stack.callback(storages[-1].close)

        def messages(wanted):
            for storage in storages:
                mine = [c for c in wanted if c.owner is storage]
                if mine:
                    yield from storage.messages(mine)

        yield [c for storage in storages for c in storage.connections], messages, store.deserialize_cdr


def _unnamed_cdr(bag: Path) -> bool:
    """A rosbag2 sqlite3 folder whose metadata.yaml gives a topic an empty serialization format."""
    try:
        info = read_yaml(bag / "metadata.yaml")["rosbag2_bagfile_information"]
        return info["storage_identifier"] == "sqlite3" and any(
            t["topic_metadata"]["serialization_format"] == "" for t in info["topics_with_message_count"])
    except (GraphcalError, OSError, KeyError, TypeError):
        return False


def decode_rosbag(bag: str | Path, topic: str | None = None, model: str | None = None,
                  distance_resolution_m: float | None = None, interpolate_azimuth: bool = True,
                  quiet: bool = False) -> VelodyneReturns:
    """Every raw return of the Velodyne packets of a bag in memory (a bag small enough to hold); arguments as
    survey_rosbag."""
    return decoded_capture(survey_rosbag(bag, topic, model, distance_resolution_m, interpolate_azimuth, quiet))


def survey_rosbag(bag: str | Path, topic: str | None = None, model: str | None = None,
                  distance_resolution_m: float | None = None, interpolate_azimuth: bool = True,
                  quiet: bool = False) -> SurveyedCapture:
    """The Velodyne packets of a bag surveyed (velodyne_pcap.survey_pcap), ready to decode in their ROS stamps'
    order: read message by message, twice, when the bag holds them in that order; else held (1206 bytes each, a
    tenth of their returns), sorted by stamp, and decoded CHUNK_PACKETS at a time."""
    bag, survey, last_s = Path(bag), PacketSurvey(), -np.inf
    options = {"path": bag, "model": model, "distance_resolution_m": distance_resolution_m,
               "interpolate_azimuth": interpolate_azimuth}
    for packets, stamps, records in packet_chunks(bag, topic):
        if stamps[0] < last_s or np.any(np.diff(stamps) < 0):
            return _sorted_survey(bag, topic, quiet, options)
        survey.add(packets, stamps, records)
        last_s = stamps[-1]

    def read_again() -> Iterator[np.ndarray]:
        return progress((packets for packets, _, _ in packet_chunks(bag, topic)), f"decoding {bag.name}", quiet=quiet)

    return surveyed_capture(survey, read_again, **options)


def _sorted_survey(bag: Path, topic: str | None, quiet: bool, options: dict) -> SurveyedCapture:
    """survey_rosbag of a bag whose packets are out of stamp order: held, sorted by stamp (stable)."""
    packets, stamps = read_velodyne_packets(bag, topic)
    order = np.argsort(stamps, kind="stable")
    packets = packets[order]
    survey = PacketSurvey()
    survey.add(packets, stamps[order], order)
    chunks = range(0, len(packets), CHUNK_PACKETS)

    def chunked() -> Iterator[np.ndarray]:
        return progress((packets[s:s + CHUNK_PACKETS] for s in chunks), f"decoding {bag.name}", total=len(chunks),
                        quiet=quiet)

    return surveyed_capture(survey, chunked, **options)


def import_rosbag(bag: str | Path, out: str | Path, *, topic: str | None = None, model: str | None = None,
                  calibration: VelodyneCalibration | None = None, interpolate_azimuth: bool = True,
                  extrinsic: Extrinsic | None = None, body_frame: str | None = None, quiet: bool = False,
                  **options) -> Recording:
    """A bag's Velodyne packets as the recording folder `out` (written whole or not at all, CHUNK_PACKETS packets
    at a time); options as velodyne_recording.write_velodyne_recording (trajectory, position, attitude_deg, crs,
    name). extrinsic: lidar -> body; when not given, from the bag's tf (rosbag_extrinsic)."""
    bag = Path(bag)
    extrinsic, extrinsic_note = rosbag_extrinsic(bag, topic, extrinsic, body_frame)
    surveyed = survey_rosbag(bag, topic, model, calibration.distance_resolution_m if calibration else None,
                             interpolate_azimuth, quiet)
    return write_velodyne_recording(surveyed, out, "velodyne-rosbag", calibration=calibration, extrinsic=extrinsic,
                                    extrinsic_note=extrinsic_note, **options)


def rosbag_extrinsic(bag: Path, topic: str | None, given: Extrinsic | None, body_frame: str | None
                     ) -> tuple[Extrinsic, str]:
    """The lidar -> body extrinsic of a bag's Velodyne packets and a note saying where it came from: as given (it
    wins), else T_body_lidar of the bag's /tf_static (ros_tf) from body_frame (by default the frame of the bag's
    Odometry or Imu messages, when it has them) to the VelodyneScan messages' header.frame_id, else identity with
    the reason (no body frame, no tf, or the chain broken: the transforms found named)."""
    with velodyne_bag(bag) as opened:
        lidar_frame = ""
        if given is None:
            body_frame = body_frame or trajectory_frame(opened)
            lidar_frame = header_frame(opened, scan_topics(opened, topic))
        return bag_extrinsic(opened, given, body_frame, lidar_frame, "the VelodyneScan messages' header.frame_id")
