"""Velodyne packets in a ROS bag (velodyne_msgs/VelodyneScan, ROS 1 or ROS 2) -> a recording.

The bag is read with rosbags (optional: `pip install "graphcal[rosbag]"`); the 1206-byte
packets go through the same decoder as pcap captures (velodyne_pcap.decode_packets), and the
packets' ROS stamps stand for the capture host clock (the hour of the sensor timestamps). A bag
carries no $GPRMC: give a position or a trajectory. docs/howto/import.md has the details.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from graphcal.common.errors import ConfigError, GraphcalError, RecordingError
from graphcal.importers.velodyne_calibration import VelodyneCalibration
from graphcal.importers.velodyne_packets import PACKET, PACKET_BYTES
from graphcal.importers.velodyne_pcap import (
    VelodyneReturns,
    decode_packets,
    recording_from_returns,
)
from graphcal.recording.directory import Recording

SCAN_TYPE = "velodyne_msgs/msg/VelodyneScan"
# ROS 2 bags do not carry message definitions: velodyne_msgs' own
_DEFINITIONS = {"velodyne_msgs/msg/VelodynePacket": "builtin_interfaces/Time stamp\nuint8[1206] data",
                SCAN_TYPE: "std_msgs/Header header\nvelodyne_msgs/VelodynePacket[] packets"}


def read_velodyne_packets(bag: str | Path, topic: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(packets as a PACKET array, their ROS stamps in s since 1970) of the VelodyneScan messages."""
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    except ImportError:
        raise ConfigError('reading ROS bags needs rosbags: pip install "graphcal[rosbag]"') from None
    bag = Path(bag)
    if not bag.exists():
        raise RecordingError(bag, "bag not found")
    store = get_typestore(Stores.ROS2_HUMBLE)
    for name, definition in _DEFINITIONS.items():
        store.register(get_types_from_msg(definition, name))
    data, stamps = [], []
    try:
        with AnyReader([bag], default_typestore=store) as reader:
            wanted = SCAN_TYPE.replace("/msg/", "/")
            scans = [c for c in reader.connections if c.msgtype.replace("/msg/", "/") == wanted
                     and (topic is None or c.topic == topic)]
            if not scans:
                found = ", ".join(sorted(f"{c.topic} ({c.msgtype})" for c in reader.connections)) or "none"
                raise RecordingError(bag, f"no {SCAN_TYPE} topic{f' named {topic}' if topic else ''}; topics: {found}",
                                     field="topic", expected="Velodyne packets (velodyne_driver output)")
            for connection, _, raw in reader.messages(connections=scans):
                for packet in reader.deserialize(raw, connection.msgtype).packets:
                    if len(packet.data) != PACKET_BYTES:
                        raise RecordingError(bag, f"packet of {len(packet.data)} bytes on {connection.topic}",
                                             expected=f"{PACKET_BYTES}-byte Velodyne data packets")
                    data.append(np.asarray(packet.data, dtype=np.uint8))
                    stamps.append(packet.stamp.sec + 1e-9 * packet.stamp.nanosec)
    except GraphcalError:
        raise
    except Exception as error:  # rosbags' own (a folder without metadata.yaml, an empty or damaged bag, a cut message)
        raise RecordingError(bag, f"not a readable ROS bag: {type(error).__name__}: {error}",
                             expected="a rosbag1 file or a rosbag2 folder with its metadata.yaml") from None
    if not data:
        raise RecordingError(bag, "no packet in the VelodyneScan messages", expected="Velodyne data packets")
    return np.stack(data).view(PACKET).ravel(), np.asarray(stamps)


def decode_rosbag(bag: str | Path, topic: str | None = None, model: str | None = None,
                  distance_resolution_m: float = 0.002, interpolate_azimuth: bool = True,
                  quiet: bool = False) -> VelodyneReturns:
    """Raw returns of the Velodyne packets of a bag (see velodyne_pcap.decode_packets)."""
    packets, stamps = read_velodyne_packets(bag, topic)
    order = np.argsort(stamps, kind="stable")
    return decode_packets(Path(bag), packets[order], stamps[order], order, model, distance_resolution_m,
                          interpolate_azimuth, quiet)


def import_rosbag(bag: str | Path, *, topic: str | None = None, model: str | None = None,
                  calibration: VelodyneCalibration | None = None, **options) -> Recording:
    """A bag's Velodyne packets as a recording; options as velodyne_pcap.import_pcap (trajectory,
    position, attitude_deg, extrinsic, interpolate_azimuth, name, quiet)."""
    quiet = options.pop("quiet", False)
    decoded = decode_rosbag(bag, topic, model, calibration.distance_resolution_m if calibration else 0.002,
                            options.pop("interpolate_azimuth", True), quiet)
    return recording_from_returns(decoded, "velodyne-rosbag", calibration=calibration, **options)
