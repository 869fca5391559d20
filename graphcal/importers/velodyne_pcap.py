"""Velodyne pcap (HDL-32E, VLP-16, HDL-64E) -> a recording (graphcal-recording/1).

`decode_pcap` reads the raw returns with a NumPy packet parser (graphcal/importers/
velodyne_packets.py): range = raw distance x 2 mm, encoder azimuth from the packet, laser id,
time = packet timestamp + the firing-time table. `import_pcap` adds the nominal sensor model,
the time base (GPS seconds of week, made absolute with the $GPRMC fixes of the position
packets, or with the capture host clock when there are none), and a trajectory: the one given,
or a static one at the GPRMC position covering the returns. docs/howto/import.md has the details.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from graphcal.common.errors import ConfigError, RecordingError
from graphcal.recording.extrinsic import Extrinsic
from graphcal.importers.gpstime import seconds_of_week
from graphcal.importers.nmea import RmcFix, find_rmc
from graphcal.importers.pcap import read_udp_payloads
from graphcal.importers.velodyne_calibration import VelodyneCalibration
from graphcal.importers.velodyne_packets import (
    DUAL_RETURN_MODE,
    LAYOUTS,
    LOWER_BLOCK,
    PACKET,
    PACKET_BYTES,
    PRODUCT_IDS,
    UPPER_BLOCK,
    PacketLayout,
    decode_returns,
    packet_rates,
    returned,
    revolution_counter,
    unwrap_hour_us,
)
from graphcal.recording.points import PointTable
from graphcal.common.progress import progress
from graphcal.recording.directory import Recording
from graphcal.recording.sensor import CATALOG, sensor_from_catalog
from graphcal.recording.trajectory import Trajectory

DATA_PORT, POSITION_PORT = 2368, 8308
POSITION_PACKET_BYTES = 512
_POSITION_STAMP_AT = 198  # uint32 us past the hour in a position packet (HDL-32E / VLP-16 manuals)
_CHUNK_PACKETS = 8192
_SYNC_TOLERANCE_S = 3.0  # an RMC sentence arrives up to about 2 s after the second it names
_MARGIN_S = 1e-3  # a static trajectory starts and ends this far beyond the returns (CSV rounding)


@dataclass(frozen=True)
class VelodyneReturns:
    """A decoded capture.

    returns: `time_s` (s past the top of the first packet's hour, on the sensor clock, float64),
    `fibre`, `range` [m], `azimuth` [rad, encoder, clockwise], `intensity`, `scan` (revolution
    index: +1 at each azimuth wrap, VeloView's frames), sorted by time.
    fixes: (sensor time s past the same hour, RMC fix) of every position packet with a fix.
    host_hour_utc_s: top of that hour by the capture host clock [s since 1970 UTC].
    """

    path: Path
    model: str
    dual_return: bool
    rotation_hz: float
    returns: dict[str, np.ndarray]
    interpolated_azimuth: bool = True
    fixes: list[tuple[float, RmcFix]] = field(default_factory=list)
    host_hour_utc_s: float = 0.0
    n_data_packets: int = 0
    n_other_packets: int = 0
    cut_bytes: int = 0


def decode_pcap(path: str | Path, model: str | None = None, distance_resolution_m: float = 0.002,
                interpolate_azimuth: bool = True, quiet: bool = False) -> VelodyneReturns:
    """Raw returns of a Velodyne capture. model forces 'HDL-32E', 'VLP-16' or 'HDL-64E' (else detected)."""
    path = Path(path)
    udp = read_udp_payloads(path)
    is_data = udp.length == PACKET_BYTES
    cut = (udp.port == DATA_PORT) & (udp.length < PACKET_BYTES)
    if cut.any():
        first = int(np.flatnonzero(cut)[0])
        raise RecordingError(path, f"record {udp.record[first]}: data packet of {udp.length[first]} bytes",
                             expected=f"{PACKET_BYTES}-byte Velodyne data packets (captured with a snap length too short?)")
    if not is_data.any():
        raise RecordingError(path, f"no Velodyne data packet among {udp.n_records} records",
                             expected=f"UDP payloads of {PACKET_BYTES} bytes (port {DATA_PORT})")
    packets = udp.stack(is_data, PACKET_BYTES).view(PACKET).ravel()
    decoded = decode_packets(path, packets, udp.time_s[is_data], udp.record[is_data], model, distance_resolution_m,
                             interpolate_azimuth, quiet)
    is_position = (udp.length == POSITION_PACKET_BYTES) & (udp.port == POSITION_PORT)
    return replace(decoded, fixes=_fixes(udp, is_data, is_position, unwrap_hour_us(packets["stamp_us"])),
                   n_other_packets=int((~is_data & ~is_position).sum()) + udp.n_records - len(udp.record),
                   cut_bytes=udp.cut_bytes)


def decode_packets(source: Path, packets: np.ndarray, host_time_s: np.ndarray, records: np.ndarray,
                   model: str | None = None, distance_resolution_m: float = 0.002, interpolate_azimuth: bool = True,
                   quiet: bool = False) -> VelodyneReturns:
    """Raw returns of data packets (structured PACKET array) from any container (pcap, rosbag).

    host_time_s: each packet's host clock time (s since 1970 UTC), for the hour of the timestamps;
    records: each packet's index in `source`, for error messages."""
    time_us = unwrap_hour_us(packets["stamp_us"])
    layout, dual = _layout(source, packets, time_us, records, model)
    returns = _decode_all(source, packets, layout, dual, time_us, distance_resolution_m, interpolate_azimuth, quiet)
    host_hour = 3600.0 * np.round((host_time_s[0] - time_us[0] * 1e-6) / 3600.0)
    return VelodyneReturns(path=source, model=layout.model, dual_return=dual,
                           rotation_hz=_rotation_hz(packets, layout, dual), returns=returns,
                           interpolated_azimuth=interpolate_azimuth, host_hour_utc_s=float(host_hour),
                           n_data_packets=len(packets))


def import_pcap(path: str | Path, *, model: str | None = None, calibration: VelodyneCalibration | None = None,
                trajectory: Trajectory | None = None, position: tuple[float, float, float] | None = None,
                attitude_deg: tuple[float, float, float] = (0.0, 0.0, 0.0), extrinsic: Extrinsic | None = None,
                interpolate_azimuth: bool = True, name: str | None = None, quiet: bool = False) -> Recording:
    """A Velodyne capture as a recording, times in GPS seconds of week.

    calibration: the unit's db.xml/YAML (required for an HDL-64E), else the catalogue model.
    trajectory: poses on the same clock (e.g. from an SBET), cut to the returns' span +- 1 s; else a
    static trajectory at
    `position` (lat, lon deg, ellipsoidal height m) or at the mean GPRMC fix (height 0 m), with
    `attitude_deg` (roll, pitch, yaw vs ENU). extrinsic: nominal lidar -> body, identity if None.
    What was assumed is listed in `recording.source['notes']`.
    """
    path = Path(path)
    decoded = decode_pcap(path, model, calibration.distance_resolution_m if calibration else 0.002,
                          interpolate_azimuth, quiet)
    return recording_from_returns(decoded, "velodyne-pcap", calibration=calibration, trajectory=trajectory,
                                  position=position, attitude_deg=attitude_deg, extrinsic=extrinsic, name=name)


def recording_from_returns(decoded: VelodyneReturns, importer: str, *, calibration: VelodyneCalibration | None = None,
                           trajectory: Trajectory | None = None, position: tuple[float, float, float] | None = None,
                           attitude_deg: tuple[float, float, float] = (0.0, 0.0, 0.0),
                           extrinsic: Extrinsic | None = None, name: str | None = None) -> Recording:
    """Decoded Velodyne returns + nominal model, time base, trajectory and extrinsic -> a recording."""
    path = decoded.path
    mode = "dual" if decoded.dual_return else "single"
    notes = [(f"{decoded.n_data_packets} {decoded.model} data packets ({mode} return), "
              f"{len(decoded.returns['time_s'])} returns, {decoded.rotation_hz:.2f} Hz")]
    if decoded.n_other_packets:
        notes.append(f"{decoded.n_other_packets} other records skipped (neither lidar data nor position packets)")
    if decoded.cut_bytes:
        notes.append(f"the capture ends inside a record (cut short): its last {decoded.cut_bytes} bytes dropped")
    sensor = _sensor(path, decoded, calibration, notes)
    hour_utc_s = _hour(decoded, notes)
    time, week = seconds_of_week(hour_utc_s, decoded.returns["time_s"])
    notes.append(f"times are GPS seconds of week {week} (sensor time past the hour + the hour in UTC + leap seconds)")
    if trajectory is None:
        trajectory = _static_trajectory(path, decoded, time, position, attitude_deg, notes)
    elif time[0] < trajectory.time[0] or time[-1] > trajectory.time[-1]:
        raise RecordingError(path, f"returns span [{time[0]:.3f}, {time[-1]:.3f}] s of GPS week {week}, the "
                                   f"trajectory [{trajectory.time[0]:.3f}, {trajectory.time[-1]:.3f}] s",
                             expected="a trajectory in GPS seconds of week covering the returns")
    else:
        trajectory = trajectory.between(time[0] - 1.0, time[-1] + 1.0)
        notes.append(f"trajectory given: {len(trajectory.time)} poses kept (the returns' span +- 1 s)")
    if extrinsic is None:
        extrinsic = Extrinsic(lever_arm_m=(0.0, 0.0, 0.0), boresight_deg=(0.0, 0.0, 0.0))
        notes.append("nominal extrinsic: identity (lidar frame = body frame)")
    returns = decoded.returns
    points = PointTable.from_arrays(time=time, fibre=returns["fibre"], range=returns["range"],
                                    azimuth=returns["azimuth"], intensity=returns["intensity"], scan=returns["scan"])
    source = {"importer": importer, "file": path.name, "model": decoded.model,
              "time_base": "GPS seconds of week", "gps_week": week,
              "azimuth": "interpolated to each firing" if decoded.interpolated_azimuth else "block azimuth",
              "notes": notes}
    return Recording(name=name or path.stem, crs="auto", sensor=sensor, extrinsic=extrinsic, trajectory=trajectory,
                     points=points, source=source)


def _fixes(udp, is_data: np.ndarray, is_position: np.ndarray, time_us: np.ndarray) -> list[tuple[float, RmcFix]]:
    """(sensor time s past the first packet's hour, fix) of the position packets with an RMC sentence;
    each position timestamp is put in the hour of the data packet before it."""
    positions = udp.stack(is_position, POSITION_PACKET_BYTES)
    stamps = positions[:, _POSITION_STAMP_AT:_POSITION_STAMP_AT + 4].copy().view("<u4").ravel().astype(np.float64)
    before = np.clip(np.searchsorted(udp.record[is_data], udp.record[is_position]) - 1, 0, len(time_us) - 1)
    stamps += 3600e6 * np.round((time_us[before] - stamps) / 3600e6)
    fixes = []
    for row, stamp_us in zip(positions, stamps):
        fix = find_rmc(row.tobytes())
        if fix is not None:
            fixes.append((stamp_us * 1e-6, fix))
    return fixes


def _decode_all(path: Path, packets: np.ndarray, layout: PacketLayout, dual: bool, time_us: np.ndarray,
                distance_m: float, interpolate_azimuth: bool, quiet: bool) -> dict[str, np.ndarray]:
    """Every return, decoded chunk by chunk into arrays allocated once, sorted by time."""
    scan = revolution_counter(packets)
    total = int(np.count_nonzero(returned(packets, layout, dual)))
    returns, at = None, 0
    chunks = range(0, len(packets), _CHUNK_PACKETS)
    for s in progress(chunks, f"decoding {path.name}", total=len(chunks), quiet=quiet):
        part = decode_returns(packets[s:s + _CHUNK_PACKETS], layout, dual, time_us[s:s + _CHUNK_PACKETS],
                              scan[s:s + _CHUNK_PACKETS], distance_m, interpolate_azimuth)
        returns = returns or {name: np.empty(total, dtype=values.dtype) for name, values in part.items()}
        size = len(part["time_s"])
        for name, values in part.items():
            returns[name][at:at + size] = values
        at += size
    if np.any(np.diff(returns["time_s"]) < 0):  # HDL-64E blocks, dual returns: equal times, other order
        order = np.argsort(returns["time_s"], kind="stable")
        for name in returns:
            returns[name] = returns[name][order]
    return returns


def _layout(path: Path, packets: np.ndarray, time_us: np.ndarray, records: np.ndarray,
            forced: str | None) -> tuple[PacketLayout, bool]:
    """The model (forced or from the packets) and the return mode, checked against the packet rate."""
    flags = packets["blocks"]["flag"]
    bad = (flags != UPPER_BLOCK) & (flags != LOWER_BLOCK)
    if bad.any():
        packet, block = (int(v) for v in np.argwhere(bad)[0])
        raise RecordingError(path, f"data packet {packet} (record {records[packet]}), block {block}: flag "
                                   f"0x{int(flags[packet, block]):04X}",
                             expected="Velodyne block flags 0xEEFF or 0xDDFF")
    has_lower = bool((flags == LOWER_BLOCK).any())
    product = int(np.bincount(packets["product"]).argmax())
    if forced is not None and forced not in LAYOUTS:
        raise ConfigError(f"unknown Velodyne model {forced!r}; known: {', '.join(LAYOUTS)}")
    detected = "HDL-64E" if has_lower else PRODUCT_IDS.get(product)
    name = forced or detected
    if name is None:
        raise RecordingError(path, f"factory byte 0x{product:02X}", field="product",
                             expected="0x21 (HDL-32E), 0x22 (VLP-16) or HDL-64E packets; force the model "
                                      "(--model) if the sensor is one of these")
    if (name == "HDL-64E") != has_lower:
        raise RecordingError(path, f"model {name} forced, but the packets {'have' if has_lower else 'have no'} "
                                   "HDL-64E lower-block flags (0xDDFF)",
                             expected=f"{detected or 'another model'} packets")
    layout = LAYOUTS[name]
    if has_lower:
        azimuth = packets["blocks"]["azimuth"]
        dual = bool(np.median(azimuth[:, 0] == azimuth[:, 2]) > 0.5)
    else:
        dual = bool(np.median(packets["return_mode"] == DUAL_RETURN_MODE) > 0.5)
    gaps = np.diff(time_us)
    gaps = gaps[gaps > 0]
    if len(gaps):
        spacing, expected = float(np.median(gaps)), layout.packet_us(dual)
        if abs(spacing / expected - 1.0) > 0.05:
            fits = [m for m, other in LAYOUTS.items() if abs(spacing / other.packet_us(dual) - 1.0) <= 0.05]
            why = f"the factory byte says 0x{product:02X}, " if forced is None and not has_lower else ""
            raise RecordingError(path, f"{why}data packets come every {spacing:.1f} us, where a {name} "
                                       f"sends one every {expected:.1f} us",
                                 expected=(f"{fits[0]} data (old VLP-16 firmware writes 0x21, the HDL-32E byte): "
                                           f"force the model (--model {fits[0]})") if fits else
                                 "a continuous capture of one of " + ", ".join(LAYOUTS))
    return layout, dual


def _rotation_hz(packets: np.ndarray, layout: PacketLayout, dual: bool) -> float:
    """Median spin rate [Hz] from each packet's azimuth advance over its firing time."""
    return float(np.round(np.median(packet_rates(packets, layout, dual)) * 1e6 / 36000.0, 3))


def _sensor(path, decoded: VelodyneReturns, calibration: VelodyneCalibration | None, notes: list[str]):
    if calibration is None:
        if decoded.model == "HDL-64E":
            raise RecordingError(path, "HDL-64E packets and no calibration file",
                                 expected="the unit's db.xml or ROS calibration YAML (--calibration)")
        notes.append(f"nominal sensor model: graphcal's {decoded.model} catalogue")
        return sensor_from_catalog(decoded.model, decoded.rotation_hz)
    sensor = calibration.sensor
    if sensor.n_fibres != LAYOUTS[decoded.model].n_lasers:
        raise RecordingError(calibration.path, f"{sensor.n_fibres} lasers", expected=f"{LAYOUTS[decoded.model].n_lasers}"
                                                                                     f" lasers for the {decoded.model} "
                                                                                     f"data of {path.name}")
    notes.append(f"nominal sensor model: {calibration.path.name}")
    notes.extend(calibration.notes())
    return type(sensor)(**{**sensor.__dict__, "model": decoded.model, "rotation_hz": decoded.rotation_hz,
                            "timing": CATALOG[decoded.model].timing})


def _hour(decoded: VelodyneReturns, notes: list[str]) -> float:
    """The top of the first packet's hour in UTC [s since 1970]: from the GPRMC fixes, else the host clock."""
    valid = [(sensor_s, fix) for sensor_s, fix in decoded.fixes if fix.valid]
    if not valid:
        notes.append("no valid $GPRMC fix: the hour of the sensor timestamps is taken from the capture host clock "
                     "(pcap record times, ROS packet stamps); times within the hour are the sensor's")
        return decoded.host_hour_utc_s
    sensor_s, fix = valid[0]
    hour = 3600.0 * np.round((fix.utc_s - sensor_s) / 3600.0)
    lag = sensor_s + hour - fix.utc_s
    if not 0.0 <= lag <= _SYNC_TOLERANCE_S:
        notes.append(f"the sensor clock is {lag:+.2f} s from the GPRMC time: it does not look synchronised to the "
                     "GNSS receiver (PPS), so the absolute times are off by about that much")
    else:
        notes.append(f"time made absolute with the GPRMC fixes (sensor clock {lag:.2f} s after the RMC second, "
                     "the usual NMEA latency)")
    return float(hour)


def _static_trajectory(path, decoded: VelodyneReturns, time: np.ndarray, position, attitude_deg,
                       notes: list[str]) -> Trajectory:
    if position is None:
        fixes = [fix for _, fix in decoded.fixes if fix.valid]
        if not fixes:
            raise RecordingError(path, "no trajectory given and no valid $GPRMC fix in the position packets",
                                 expected="a position (--position LAT,LON,ALT) or a trajectory (--trajectory)")
        position = (float(np.mean([f.lat_deg for f in fixes])), float(np.mean([f.lon_deg for f in fixes])), 0.0)
        where = f"the mean of {len(fixes)} GPRMC fixes, height 0 m (RMC has no height)"
    else:
        where = "the position given"
    start, end = float(time[0]) - _MARGIN_S, float(time[-1]) + _MARGIN_S
    notes.append(f"STATIC trajectory (the sensor is assumed not to move): lat {position[0]:.7f}, lon "
                 f"{position[1]:.7f}, height {position[2]:.2f} m ({where}), attitude {tuple(attitude_deg)} deg vs ENU, "
                 f"over [{start:.6f}, {end:.6f}] s")
    return Trajectory(time=np.array([start, end]), position=np.array([position, position], dtype=np.float64),
                      rpy_deg=np.array([attitude_deg, attitude_deg], dtype=np.float64), geodetic=True)
