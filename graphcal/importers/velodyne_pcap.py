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
from graphcal.importers.trajectory_span import capture_trajectory
from graphcal.importers.velodyne_calibration import VelodyneCalibration
from graphcal.importers.velodyne_packets import (
    BANK_FLAGS,
    DUAL_RETURN_MODE,
    LAYOUTS,
    LOWER_BLOCK,
    PACKET,
    PACKET_BYTES,
    PRODUCT_IDS,
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
_GENERIC_CALIBRATION = {"VLP-32C": "VLP32.yaml", "VLS-128": "VLS128.yaml"}  # the drivers' model files
_VLS128_PACKET_US = (150.0, 180.0)  # packet periods of VLS-128 firmware versions (160 to 173.3 us)


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
    distance_m: float = 0.002


def decode_pcap(path: str | Path, model: str | None = None, distance_resolution_m: float | None = None,
                interpolate_azimuth: bool = True, quiet: bool = False) -> VelodyneReturns:
    """Raw returns of a Velodyne capture. model forces one of velodyne_packets.LAYOUTS (else detected);
    distance_resolution_m: an HDL-64E's packet distance unit from its calibration (see decode_packets)."""
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
                   model: str | None = None, distance_resolution_m: float | None = None, interpolate_azimuth: bool = True,
                   quiet: bool = False) -> VelodyneReturns:
    """Raw returns of data packets (structured PACKET array) from any container (pcap, rosbag).

    host_time_s: each packet's host clock time (s since 1970 UTC), for the hour of the timestamps;
    records: each packet's index in `source`, for error messages. The distance unit is the model's
    (2 or 4 mm, velodyne_packets.LAYOUTS); an HDL-64E's calibration file states its own
    (db.xml distLSB_), which distance_resolution_m passes on."""
    time_us = unwrap_hour_us(packets["stamp_us"])
    layout, dual = _layout(source, packets, time_us, records, model)
    unit_m = distance_resolution_m if layout.model == "HDL-64E" and distance_resolution_m else layout.distance_m
    returns = _decode_all(source, packets, layout, dual, time_us, unit_m, interpolate_azimuth, quiet)
    host_hour = 3600.0 * np.round((host_time_s[0] - time_us[0] * 1e-6) / 3600.0)
    return VelodyneReturns(path=source, model=layout.model, dual_return=dual,
                           rotation_hz=_rotation_hz(packets, layout, dual), returns=returns,
                           interpolated_azimuth=interpolate_azimuth, host_hour_utc_s=float(host_hour),
                           n_data_packets=len(packets), distance_m=unit_m)


def import_pcap(path: str | Path, *, model: str | None = None, calibration: VelodyneCalibration | None = None,
                trajectory: Trajectory | None = None, position: tuple[float, float, float] | None = None,
                attitude_deg: tuple[float, float, float] = (0.0, 0.0, 0.0), extrinsic: Extrinsic | None = None,
                interpolate_azimuth: bool = True, name: str | None = None, quiet: bool = False) -> Recording:
    """A Velodyne capture as a recording, times in GPS seconds of week.

    calibration: the unit's db.xml/YAML (required for an HDL-64E, a VLP-32C and a VLS-128), else the
    catalogue model.
    trajectory: poses on the same clock (e.g. from an SBET), cut to the returns' span +- 1 s; else a
    static trajectory at
    `position` (lat, lon deg, ellipsoidal height m) or at the mean GPRMC fix (height 0 m), with
    `attitude_deg` (roll, pitch, yaw vs ENU). extrinsic: nominal lidar -> body, identity if None.
    What was assumed is listed in `recording.source['notes']`.
    """
    path = Path(path)
    decoded = decode_pcap(path, model, calibration.distance_resolution_m if calibration else None,
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
    where = "the position given"
    if trajectory is None and position is None:
        position, where = _position_of_fixes(path, decoded)
    trajectory = capture_trajectory(path, time, week, trajectory, position, attitude_deg, notes, where)
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
    next_us = np.append(time_us[1:], np.nan)
    next_azimuth = np.append(packets["blocks"]["azimuth"][1:, 0].astype(np.float64), np.nan)
    returns, at = None, 0
    chunks = range(0, len(packets), _CHUNK_PACKETS)
    for s in progress(chunks, f"decoding {path.name}", total=len(chunks), quiet=quiet):
        part = decode_returns(packets[s:s + _CHUNK_PACKETS], layout, dual, time_us[s:s + _CHUNK_PACKETS],
                              scan[s:s + _CHUNK_PACKETS], distance_m, interpolate_azimuth,
                              (next_us[s:s + _CHUNK_PACKETS], next_azimuth[s:s + _CHUNK_PACKETS]))
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
    bad = ~np.isin(flags, BANK_FLAGS)
    if bad.any():
        packet, block = (int(v) for v in np.argwhere(bad)[0])
        raise RecordingError(path, f"data packet {packet} (record {records[packet]}), block {block}: flag "
                                   f"0x{int(flags[packet, block]):04X}",
                             expected="Velodyne block flags 0xEEFF, 0xDDFF, 0xCCFF or 0xBBFF")
    banks = 4 if np.isin(flags, BANK_FLAGS[2:]).any() else 2 if (flags == LOWER_BLOCK).any() else 1
    product = int(np.bincount(packets["product"]).argmax())
    if forced is not None and forced not in LAYOUTS:
        raise ConfigError(f"unknown Velodyne model {forced!r}; known: {', '.join(LAYOUTS)}")
    detected = {2: "HDL-64E", 4: "VLS-128"}.get(banks, PRODUCT_IDS.get(product))
    name = forced or detected
    if name is None:
        raise RecordingError(path, f"factory byte 0x{product:02X}", field="product",
                             expected=", ".join(f"0x{k:02X} ({m})" for k, m in PRODUCT_IDS.items())
                             + " or HDL-64E packets; force the model (--model) if the sensor is one of these")
    layout = LAYOUTS[name]
    if layout.blocks_per_column != banks:
        wanted = max(layout.blocks_per_column, banks)
        what = {2: "HDL-64E lower-block flags (0xDDFF)", 4: "VLS-128 bank flags (0xCCFF, 0xBBFF)"}[wanted]
        raise RecordingError(path, f"model {name} forced, but the packets {'have' if banks == wanted else 'have no'} "
                                   f"{what}", expected=f"{detected or 'another model'} packets")
    if banks == 2:
        azimuth = packets["blocks"]["azimuth"]
        dual = bool(np.median(azimuth[:, 0] == azimuth[:, 2]) > 0.5)
    else:
        dual = bool(np.median(packets["return_mode"] == DUAL_RETURN_MODE) > 0.5)
    if dual and name == "VLS-128":
        raise RecordingError(path, "VLS-128 dual-return packets", field="return_mode",
                             expected="single-return (strongest or last) VLS-128 data; dual return is not supported")
    gaps = np.diff(time_us)
    gaps = gaps[gaps > 0]
    if len(gaps) and name == "VLS-128" and _VLS128_PACKET_US[0] <= np.median(gaps) <= _VLS128_PACKET_US[1]:
        # three firing sequences per packet; their period depends on the firmware (53.3 us in the
        # drivers, 2.89 us firing groups since firmware 5.2.3): taken from the packet rate
        layout = replace(layout, column_us=float(np.median(gaps)) / 3)
    if len(gaps):
        spacing, expected = float(np.median(gaps)), layout.packet_us(dual)
        if abs(spacing / expected - 1.0) > 0.05:
            fits = [m for m, other in LAYOUTS.items() if abs(spacing / other.packet_us(dual) - 1.0) <= 0.05]
            why = f"the factory byte says 0x{product:02X}, " if forced is None and banks == 1 else ""
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
        if decoded.model == "HDL-64E" or decoded.model not in CATALOG:  # per-unit or per-model tables only
            generic = _GENERIC_CALIBRATION.get(decoded.model)
            raise RecordingError(path, f"{decoded.model} packets and no calibration file",
                                 expected="the unit's db.xml or ROS calibration YAML (--calibration)"
                                          + (f", or the model's generic {generic} of the ROS velodyne driver or "
                                             "nebula" if generic else ""))
        notes.append(f"nominal sensor model: graphcal's {decoded.model} catalogue")
        return sensor_from_catalog(decoded.model, decoded.rotation_hz)
    sensor = calibration.sensor
    if sensor.n_fibres != LAYOUTS[decoded.model].n_lasers:
        raise RecordingError(calibration.path, f"{sensor.n_fibres} lasers", expected=f"{LAYOUTS[decoded.model].n_lasers}"
                                                                                     f" lasers for the {decoded.model} "
                                                                                     f"data of {path.name}")
    notes.append(f"nominal sensor model: {calibration.path.name}")
    notes.extend(calibration.notes())
    if abs(calibration.distance_resolution_m - decoded.distance_m) > 1e-9:
        notes.append(f"{calibration.path.name} states a distance resolution of {calibration.distance_resolution_m} m; "
                     f"the {decoded.model} packets count in {decoded.distance_m} m units (its manual), which are used")
    timing = CATALOG[decoded.model].timing if decoded.model in CATALOG else None
    return type(sensor)(**{**sensor.__dict__, "model": decoded.model, "rotation_hz": decoded.rotation_hz,
                            "timing": timing})


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


def _position_of_fixes(path, decoded: VelodyneReturns) -> tuple[tuple[float, float, float], str]:
    """The static position of a capture without trajectory or --position: the mean of its valid $GPRMC fixes
    (height 0 m: RMC has none), and where it comes from in words; RecordingError when there is none."""
    fixes = [fix for _, fix in decoded.fixes if fix.valid]
    if not fixes:
        raise RecordingError(path, "no trajectory given and no valid $GPRMC fix in the position packets",
                             expected="a position (--position LAT,LON,ALT) or a trajectory (--trajectory)")
    position = (float(np.mean([f.lat_deg for f in fixes])), float(np.mean([f.lon_deg for f in fixes])), 0.0)
    return position, f"the mean of {len(fixes)} GPRMC fixes, height 0 m (RMC has no height)"
