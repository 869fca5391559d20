"""Ouster pcap (OS-0/OS-1/OS-2, single-return profiles) + metadata JSON -> a recording.

`decode_ouster_pcap` reads the lidar packets (graphcal/importers/ouster_packets.py) with the
unit's data format from the metadata (graphcal/importers/ouster_metadata.py): one return per
pixel with a range, time = its column's timestamp, azimuth = 2 pi measurement_id / columns per
frame (clockwise, graphcal's convention), fibre = pixel row (the beam of the metadata's angle
lists). `import_ouster` adds the factory beam model (with the beam-origin offset), the time base
(GPS seconds of week), a trajectory (the one given, or a static one at --position) and the
extrinsic: lidar -> body = (sensor -> body, the mount given) * lidar_to_sensor_transform.
docs/howto/import-ouster.md has the details.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from graphcal.common.errors import RecordingError
from graphcal.importers.gpstime import seconds_of_week
from graphcal.importers.ouster_metadata import OusterMetadata
from graphcal.importers.ouster_packets import LAYOUTS, decode_columns
from graphcal.importers.pcap import read_udp_payloads
from graphcal.importers.trajectory_span import capture_trajectory
from graphcal.recording.directory import Recording
from graphcal.recording.extrinsic import Extrinsic
from graphcal.recording.points import PointTable
from graphcal.recording.rotations import rpy_deg_from_rotation
from graphcal.recording.trajectory import Trajectory

_ABSOLUTE_CLOCK_S = 1e9  # timestamps above this many seconds are wall-clock time (after 2001), not since power-on


@dataclass(frozen=True)
class OusterReturns:
    """A decoded capture. returns: `timestamp_ns` (int64, sensor clock), `fibre`, `range` [m],
    `azimuth` [rad, clockwise], `intensity` (reflectivity 0-255), `scan` (frame counter from 0),
    sorted by time. host_first_s: capture host time of the first lidar packet [s since 1970]."""

    path: Path
    metadata: OusterMetadata
    returns: dict[str, np.ndarray]
    host_first_s: float
    n_packets: int
    n_columns: int
    n_invalid_columns: int
    n_other_records: int
    cut_bytes: int = 0


def decode_ouster_pcap(path: str | Path, metadata: OusterMetadata) -> OusterReturns:
    """Every return of the lidar packets of a capture that match `metadata`'s data format."""
    path = Path(path)
    udp = read_udp_payloads(path)
    size = LAYOUTS[metadata.udp_profile_lidar].packet_bytes(metadata.columns_per_packet, metadata.pixels_per_column)
    is_lidar = udp.length == size
    on_port = udp.port == metadata.udp_port_lidar
    if not is_lidar.any():
        lengths = np.unique(udp.length[on_port])
        raise RecordingError(path, f"no lidar packet of {size} bytes among {udp.n_records} records"
                                   + (f" (port {metadata.udp_port_lidar} has {lengths.tolist()[:4]} bytes)"
                                      if len(lengths) else ""),
                             expected=f"{metadata.udp_profile_lidar} packets of {metadata.columns_per_packet} columns x "
                                      f"{metadata.pixels_per_column} pixels, as {metadata.path.name} says (is it this "
                                      "unit's metadata, from the same session?)")
    packets = udp.stack(is_lidar, size)
    _check_unit(path, metadata, packets)
    columns = decode_columns(packets, metadata.udp_profile_lidar, metadata.columns_per_packet,
                             metadata.pixels_per_column)
    width = metadata.columns_per_frame
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
    scan = _frame_counter(columns.frame_id[valid])[column]
    timestamp = columns.timestamp_ns[rows].astype(np.int64)
    returns = {"timestamp_ns": timestamp, "fibre": fibre.astype(np.int16),
               "range": range_mm[column, fibre].astype(np.float64) / 1000.0,
               "azimuth": 2.0 * np.pi * columns.measurement_id[rows].astype(np.float64) / width,
               "intensity": columns.reflectivity[valid][column, fibre].astype(np.float32), "scan": scan}
    order = np.argsort(timestamp, kind="stable")
    returns = {name: values[order] for name, values in returns.items()}
    return OusterReturns(path=path, metadata=metadata, returns=returns, host_first_s=float(udp.time_s[is_lidar][0]),
                         n_packets=len(packets), n_columns=len(valid), n_invalid_columns=int((~columns.valid).sum()),
                         n_other_records=udp.n_records - len(packets), cut_bytes=udp.cut_bytes)


def import_ouster(path: str | Path, metadata: OusterMetadata, *, trajectory: Trajectory | None = None,
                  position: tuple[float, float, float] | None = None,
                  attitude_deg: tuple[float, float, float] = (0.0, 0.0, 0.0), mount: Extrinsic | None = None,
                  name: str | None = None) -> Recording:
    """An Ouster capture as a recording, times in GPS seconds of week.

    trajectory: poses on the same clock, cut to the returns' span +- 1 s; else a static one at
    `position` (lat, lon deg, ellipsoidal height m) with `attitude_deg` (roll, pitch, yaw vs ENU).
    mount: the Ouster *sensor* frame -> body (identity if None); the extrinsic written is lidar ->
    body, the mount times the metadata's lidar_to_sensor_transform. What was assumed is listed in
    `recording.source['notes']`.
    """
    decoded = decode_ouster_pcap(path, metadata)
    returns = decoded.returns
    if not len(returns["timestamp_ns"]):
        raise RecordingError(decoded.path, "no return (every pixel of every valid column has range 0)",
                             expected="a capture of a running sensor")
    notes = [f"{decoded.n_packets} {metadata.prod_line} lidar packets ({metadata.udp_profile_lidar}, "
             f"{metadata.columns_per_frame}x{metadata.rotation_hz:g}), {decoded.n_columns} valid columns, "
             f"{len(returns['timestamp_ns'])} returns in {int(returns['scan'][-1]) + 1} frames"]
    if decoded.n_invalid_columns:
        notes.append(f"{decoded.n_invalid_columns} columns flagged invalid (status bit 0 clear) skipped")
    if decoded.n_other_records:
        notes.append(f"{decoded.n_other_records} other records skipped (IMU packets, other traffic)")
    if decoded.cut_bytes:
        notes.append(f"the capture ends inside a record (cut short): its last {decoded.cut_bytes} bytes dropped")
    notes.append(f"nominal sensor model: the beam intrinsics of {metadata.path.name} (beam origin "
                 f"{metadata.beam_to_lidar[0, 3]:.3f} mm from the axis), in the Ouster lidar frame")
    time, week = _gps_time(decoded, notes)
    path = decoded.path
    if trajectory is None and position is None:
        raise RecordingError(path, "no trajectory given, and Ouster lidar packets carry no position",
                             expected="a position (--position LAT,LON,ALT) or a trajectory (--trajectory)")
    trajectory = capture_trajectory(path, time, week, trajectory, position, attitude_deg, notes)
    extrinsic = lidar_to_body(metadata, mount, notes)
    points = PointTable.from_arrays(time=time, fibre=returns["fibre"], range=returns["range"],
                                    azimuth=returns["azimuth"], intensity=returns["intensity"], scan=returns["scan"])
    source = {"importer": "ouster-pcap", "file": path.name, "metadata": metadata.path.name,
              "model": metadata.prod_line, "time_base": "GPS seconds of week", "gps_week": week,
              "azimuth": "2 pi measurement_id / columns_per_frame (clockwise)", "notes": notes}
    return Recording(name=name or path.stem, crs="auto", sensor=metadata.sensor_model(), extrinsic=extrinsic,
                     trajectory=trajectory, points=points, source=source)


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


def _frame_counter(frame_id: np.ndarray) -> np.ndarray:
    """u16 frame ids (wrapping) -> frame counter from 0, int32."""
    steps = np.diff(frame_id.astype(np.int64)) % 65536
    return np.concatenate([[0], np.cumsum(steps)]).astype(np.int32)


def _gps_time(decoded: OusterReturns, notes: list[str]) -> tuple[np.ndarray, int]:
    """Column timestamps -> GPS seconds of week (float64), and the week."""
    stamps = decoded.returns["timestamp_ns"]
    first_s = stamps[0] // 1_000_000_000
    if first_s > _ABSOLUTE_CLOCK_S:
        base, offset = float(first_s), (stamps - first_s * 1_000_000_000) * 1e-9
        notes.append("sensor timestamps are wall-clock time (PTP or GNSS-synchronised): read as UTC; a PTP master "
                     "serving TAI makes them 37 s late")
    else:
        host = decoded.host_first_s
        base = float(np.floor(host))
        offset = (host - base) + (stamps - stamps[0]) * 1e-9
        notes.append(f"sensor timestamps count from power-on ({stamps[0] * 1e-9:.3f} s at the first return, internal "
                     "clock): made absolute with the capture host clock at the first lidar packet (host clock error "
                     "and network latency included)")
    time, week = seconds_of_week(base, offset)
    notes.append(f"times are GPS seconds of week {week}")
    return time, week
