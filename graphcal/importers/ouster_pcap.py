"""Ouster pcap (OS-0/OS-1/OS-2, single-return profiles) + metadata JSON -> a recording, streamed.

The lidar packets (graphcal/importers/ouster_packets.py, the unit's data format from the metadata:
graphcal/importers/ouster_metadata.py) give one return per pixel with a range: time = its column's
timestamp, azimuth = 2 pi measurement_id / columns per frame (clockwise, graphcal's convention),
fibre = pixel row (the beam of the metadata's angle lists). The libpcap file is read twice,
chunk_bytes at a time: a first pass (`survey_ouster_pcap`) counts the packets and finds the
earliest and latest return (the time base: GPS seconds of week), the second decodes the packets
chunk by chunk into points.parquet (return_stream), the folder appearing whole or not at all.
Memory holds a chunk of the file and its returns, whatever the capture's length. `import_ouster`
adds the factory beam model (with the beam-origin offset), a trajectory (the one given, or a
static one at --position) and the extrinsic: lidar -> body = (sensor -> body, the mount given) *
lidar_to_sensor_transform. docs/howto/import-ouster.md has the details.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from graphcal.common.errors import RecordingError
from graphcal.common.progress import progress
from graphcal.importers.gpstime import seconds_of_week
from graphcal.importers.ouster_metadata import OusterMetadata
from graphcal.importers.ouster_packets import LAYOUTS, decode_columns
from graphcal.importers.pcap import UdpPayloads, chunk_count, udp_payload_chunks
from graphcal.importers.return_stream import write_import
from graphcal.importers.trajectory_span import capture_trajectory
from graphcal.recording.directory import Recording
from graphcal.recording.extrinsic import Extrinsic
from graphcal.recording.rotations import rpy_deg_from_rotation
from graphcal.recording.trajectory import Trajectory

CHUNK_BYTES = 2**22  # libpcap bytes read at a time: about 170 OS-1-128 packets of 1024x10, 0.3 M returns
_ABSOLUTE_CLOCK_S = 1e9  # timestamps above this many seconds are wall-clock time (after 2001), not since power-on
_ORDER = "lidar packets in time order (as a capture records them), out of order by less than a chunk of packets"
_POINT_COLUMNS = ("fibre", "range", "azimuth", "intensity", "scan")


@dataclass(frozen=True)
class _Chunk:
    """The lidar packets of a chunk of the file decoded. returns: `timestamp_ns` (int64, sensor clock), `fibre`,
    `range` [m], `azimuth` [rad, clockwise], `intensity` (reflectivity 0-255), `scan` (frame counter from the
    capture's first valid column), in packet/column/pixel order; udp: the chunk's UDP payloads, is_lidar: which of
    them are lidar packets; n_valid / n_invalid: columns with status bit 0 set / clear."""

    returns: dict[str, np.ndarray]
    udp: UdpPayloads
    is_lidar: np.ndarray
    n_valid: int
    n_invalid: int


@dataclass
class OusterCapture:
    """What the lidar packets of a whole capture say, gathered chunk by chunk in file order (the first pass).

    first_ns / last_ns: the earliest and the latest timestamp of a return [ns, sensor clock]; last_scan: the frame
    counter of the latest return (the last of those at last_ns in file order); host_first_s: capture host time of
    the first lidar packet [s since 1970]; port_lengths: the payload sizes [bytes] seen on the metadata's lidar
    port; cut_bytes: the bytes of an incomplete last record dropped."""

    path: Path
    metadata: OusterMetadata
    n_records: int = 0
    n_packets: int = 0
    n_columns: int = 0
    n_invalid_columns: int = 0
    n_returns: int = 0
    cut_bytes: int = 0
    host_first_s: float = float("nan")
    first_ns: int = 0
    last_ns: int = -1
    last_scan: int = 0
    port_lengths: set[int] = field(default_factory=set)

    @property
    def n_other_records(self) -> int:
        return self.n_records - self.n_packets

    def add(self, chunk: _Chunk) -> None:
        udp, stamps = chunk.udp, chunk.returns["timestamp_ns"]
        lidar = int(np.count_nonzero(chunk.is_lidar))
        if lidar and not self.n_packets:
            self.host_first_s = float(udp.time_s[chunk.is_lidar][0])
        self.port_lengths.update(udp.length[udp.port == self.metadata.udp_port_lidar].tolist())
        self.n_records += udp.n_records
        self.n_packets += lidar
        self.n_columns += chunk.n_valid
        self.n_invalid_columns += chunk.n_invalid
        self.cut_bytes = udp.cut_bytes
        if len(stamps):
            self.first_ns = min(self.first_ns, int(stamps.min())) if self.n_returns else int(stamps.min())
            top = int(stamps.max())
            if top >= self.last_ns:
                self.last_ns, self.last_scan = top, int(chunk.returns["scan"][np.flatnonzero(stamps == top)[-1]])
        self.n_returns += len(stamps)


def survey_ouster_pcap(path: str | Path, metadata: OusterMetadata, chunk_bytes: int | None = CHUNK_BYTES,
                       quiet: bool = True) -> OusterCapture:
    """The first pass over a capture: its lidar packets that match `metadata`'s data format, counted, read
    chunk_bytes of the file at a time (the whole file when None); RecordingError naming the file when it has none
    of them, packets of another unit, or no return."""
    path = Path(path)
    capture = OusterCapture(path, metadata)
    for chunk in _chunks(path, metadata, chunk_bytes, "surveying", quiet):
        capture.add(chunk)
    if not capture.n_packets:
        size = _packet_bytes(metadata)
        lengths = sorted(capture.port_lengths)
        raise RecordingError(path, f"no lidar packet of {size} bytes among {capture.n_records} records"
                                   + (f" (port {metadata.udp_port_lidar} has {lengths[:4]} bytes)" if lengths else ""),
                             expected=f"{metadata.udp_profile_lidar} packets of {metadata.columns_per_packet} columns x "
                                      f"{metadata.pixels_per_column} pixels, as {metadata.path.name} says (is it this "
                                      "unit's metadata, from the same session?)")
    if not capture.n_returns:
        raise RecordingError(path, "no return (every pixel of every valid column has range 0)",
                             expected="a capture of a running sensor")
    return capture


def _packet_bytes(metadata: OusterMetadata) -> int:
    return LAYOUTS[metadata.udp_profile_lidar].packet_bytes(metadata.columns_per_packet, metadata.pixels_per_column)


def _chunks(path: Path, metadata: OusterMetadata, chunk_bytes: int | None, doing: str, quiet: bool
            ) -> Iterator[_Chunk]:
    """The capture's lidar packets decoded chunk after chunk (the frame counter carried over); the first packet's
    unit checked against the metadata, every valid column's measurement_id against the frame width."""
    size, width, frames, checked = _packet_bytes(metadata), metadata.columns_per_frame, _FrameCounter(), False
    for udp in progress(udp_payload_chunks(path, chunk_bytes), f"{doing} {path.name}",
                        total=chunk_count(path, chunk_bytes), quiet=quiet):
        is_lidar = udp.length == size
        packets = udp.stack(is_lidar, size)
        if len(packets) and not checked:
            _check_unit(path, metadata, packets)
            checked = True
        columns = decode_columns(packets, metadata.udp_profile_lidar, metadata.columns_per_packet,
                                 metadata.pixels_per_column)
        bad = columns.valid & (columns.measurement_id >= width)
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            raise RecordingError(path, f"record {udp.record[is_lidar][columns.packet[row]]}: measurement_id "
                                       f"{columns.measurement_id[row]}", field="measurement_id",
                                 expected=f"a column index below {width} (lidar_mode of {metadata.path.name})")
        valid = np.flatnonzero(columns.valid)
        range_mm = columns.range_mm[valid]
        column, fibre = np.nonzero(range_mm)
        rows = valid[column]
        returns = {"timestamp_ns": columns.timestamp_ns[rows].astype(np.int64), "fibre": fibre.astype(np.int16),
                   "range": range_mm[column, fibre].astype(np.float64) / 1000.0,
                   "azimuth": 2.0 * np.pi * columns.measurement_id[rows].astype(np.float64) / width,
                   "intensity": columns.reflectivity[valid][column, fibre].astype(np.float32),
                   "scan": frames(columns.frame_id[valid])[column]}
        yield _Chunk(returns, udp, is_lidar, len(valid), int(np.count_nonzero(~columns.valid)))


def import_ouster(path: str | Path, metadata: OusterMetadata, out: str | Path, *, trajectory: Trajectory | None = None,
                  position: tuple[float, float, float] | None = None,
                  attitude_deg: tuple[float, float, float] = (0.0, 0.0, 0.0), mount: Extrinsic | None = None,
                  crs: str = "auto", name: str | None = None, chunk_bytes: int | None = CHUNK_BYTES,
                  quiet: bool = False) -> Recording:
    """An Ouster capture as the recording folder `out` (written whole or not at all, chunk by chunk; an existing
    folder is replaced), times in GPS seconds of week.

    trajectory: poses on the same clock, cut to the returns' span +- 1 s; else a static one at
    `position` (lat, lon deg, ellipsoidal height m) with `attitude_deg` (roll, pitch, yaw vs ENU).
    mount: the Ouster *sensor* frame -> body (identity if None); the extrinsic written is lidar ->
    body, the mount times the metadata's lidar_to_sensor_transform. crs: the world CRS (auto: from the
    trajectory). chunk_bytes: how much of the file is read at a time (the whole file when None). What was
    assumed is listed in `recording.source['notes']`.
    """
    path = Path(path)
    capture = survey_ouster_pcap(path, metadata, chunk_bytes, quiet)
    notes = [f"{capture.n_packets} {metadata.prod_line} lidar packets ({metadata.udp_profile_lidar}, "
             f"{metadata.columns_per_frame}x{metadata.rotation_hz:g}), {capture.n_columns} valid columns, "
             f"{capture.n_returns} returns in {capture.last_scan + 1} frames"]
    if capture.n_invalid_columns:
        notes.append(f"{capture.n_invalid_columns} columns flagged invalid (status bit 0 clear) skipped")
    if capture.n_other_records:
        notes.append(f"{capture.n_other_records} other records skipped (IMU packets, other traffic)")
    if capture.cut_bytes:
        notes.append(f"the capture ends inside a record (cut short): its last {capture.cut_bytes} bytes dropped")
    notes.append(f"nominal sensor model: the beam intrinsics of {metadata.path.name} (beam origin "
                 f"{metadata.beam_to_lidar[0, 3]:.3f} mm from the axis), in the Ouster lidar frame")
    if trajectory is None and position is None:
        raise RecordingError(path, "no trajectory given, and Ouster lidar packets carry no position",
                             expected="a position (--position LAT,LON,ALT) or a trajectory (--trajectory)")
    gps_time, week = _gps_time(capture, notes)
    span = gps_time(np.array([capture.first_ns, capture.last_ns], dtype=np.int64))
    trajectory = capture_trajectory(path, span, week, trajectory, position, attitude_deg, notes)
    extrinsic = lidar_to_body(metadata, mount, notes)
    source = {"importer": "ouster-pcap", "file": path.name, "metadata": metadata.path.name,
              "model": metadata.prod_line, "time_base": "GPS seconds of week", "gps_week": week,
              "azimuth": "2 pi measurement_id / columns_per_frame (clockwise)", "notes": notes}

    def chunks() -> Iterator[tuple[dict[str, np.ndarray], None]]:
        for chunk in _chunks(path, metadata, chunk_bytes, "decoding", quiet):
            stamps = chunk.returns["timestamp_ns"]
            if len(stamps):
                yield {"time": gps_time(stamps), **{key: chunk.returns[key] for key in _POINT_COLUMNS}}, None

    return write_import(Path(out), path, _ORDER, chunks(), lambda _, points: Recording(
        name=name or path.stem, crs=crs, sensor=metadata.sensor_model(), extrinsic=extrinsic, trajectory=trajectory,
        points=points, source=source))


def lidar_to_body(metadata: OusterMetadata, mount: Extrinsic | None, notes: list[str]) -> Extrinsic:
    """The extrinsic of the recording: mount (sensor -> body) * lidar_to_sensor_transform (mm -> m)."""
    if mount is None:
        mount = Extrinsic(lever_arm_m=(0.0, 0.0, 0.0), boresight_deg=(0.0, 0.0, 0.0))
        notes.append("nominal extrinsic: the metadata's lidar_to_sensor_transform (body frame = Ouster sensor frame)")
    else:
        notes.append("nominal extrinsic: the mount given (sensor frame -> body) times the metadata's "
                     "lidar_to_sensor_transform")
    rotation = mount.R_body_lidar @ metadata.lidar_to_sensor[:3, :3]
    lever_arm = mount.R_body_lidar @ (metadata.lidar_to_sensor[:3, 3] / 1000.0) + np.asarray(mount.lever_arm_m)
    boresight = rpy_deg_from_rotation(Rotation.from_matrix(rotation))
    return Extrinsic(lever_arm_m=tuple(float(v) for v in lever_arm), boresight_deg=tuple(float(v) for v in boresight))


def _check_unit(path: Path, metadata: OusterMetadata, packets: np.ndarray) -> None:
    """Refuse packets whose header names another unit than the metadata (non-legacy headers carry its serial)."""
    if not LAYOUTS[metadata.udp_profile_lidar].packet_header:
        return
    expected = metadata.raw.get("prod_sn", (metadata.raw.get("sensor_info") or {}).get("prod_sn"))
    try:
        expected = int(expected)
    except (TypeError, ValueError):
        return
    serial = packets[0, 7:12].astype(np.uint64) << np.arange(0, 40, 8, dtype=np.uint64)
    serial = int(serial.sum())
    if serial and expected and serial != expected:
        raise RecordingError(path, f"packets of unit {serial}", field="prod_sn",
                             expected=f"unit {expected} of {metadata.path.name} (the metadata of the unit that "
                                      "recorded the capture)")


class _FrameCounter:
    """The u16 frame ids (wrapping) of the valid columns, chunk after chunk -> a frame counter from 0 (int32)."""

    def __init__(self):
        self._last: int | None = None  # the frame id of the last valid column so far
        self._count = 0

    def __call__(self, frame_id: np.ndarray) -> np.ndarray:
        ids = frame_id.astype(np.int64)
        if not len(ids):
            return np.zeros(0, dtype=np.int32)
        counter = self._count + np.cumsum(np.diff(ids, prepend=ids[0] if self._last is None else self._last) % 65536)
        self._last, self._count = int(ids[-1]), int(counter[-1])
        return counter.astype(np.int32)


def _gps_time(capture: OusterCapture, notes: list[str]) -> tuple[Callable[[np.ndarray], np.ndarray], int]:
    """Column timestamps [ns, int64] -> GPS seconds of week (float64) of the capture's week, and the week: the
    timestamps as UTC when they are wall-clock time, else counted from the capture host clock at the first lidar
    packet."""
    first_ns = capture.first_ns
    first_s = first_ns // 1_000_000_000
    if first_s > _ABSOLUTE_CLOCK_S:
        base = float(first_s)

        def offset(stamps: np.ndarray) -> np.ndarray:
            return (stamps - first_s * 1_000_000_000) * 1e-9

        notes.append("sensor timestamps are wall-clock time (PTP or GNSS-synchronised): read as UTC; a PTP master "
                     "serving TAI makes them 37 s late")
    else:
        host = capture.host_first_s
        base = float(np.floor(host))

        def offset(stamps: np.ndarray) -> np.ndarray:
            return (host - base) + (stamps - first_ns) * 1e-9

        notes.append(f"sensor timestamps count from power-on ({first_ns * 1e-9:.3f} s at the first return, internal "
                     "clock): made absolute with the capture host clock at the first lidar packet (host clock error "
                     "and network latency included)")
    _, week = seconds_of_week(base, offset(np.array([first_ns], dtype=np.int64)))
    notes.append(f"times are GPS seconds of week {week}")
    return lambda stamps: seconds_of_week(base, offset(stamps), week)[0], week
