"""Velodyne data packets (of a pcap capture or a ROS bag), surveyed once, then decoded chunk by chunk into a
recording folder (or into arrays, for a capture small enough to hold).

The survey (velodyne_survey) decides the model, the return mode and the hour of the timestamps; the recording gets
the nominal sensor model, the time base (GPS seconds of week, the hour from the $GPRMC fixes or the host clock) and a
trajectory: the one given, cut to the returns, or a static one at a position or at the mean GPRMC fix. The returns
go to points.parquet as they are decoded (return_stream), the folder appears whole or not at all.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from graphcal.common.atomic import atomic_directory
from graphcal.common.errors import RecordingError
from graphcal.importers.gpstime import seconds_of_week
from graphcal.importers.return_stream import POINTS, return_writer, save_imported
from graphcal.importers.trajectory_span import capture_trajectory
from graphcal.importers.velodyne_calibration import VelodyneCalibration
from graphcal.importers.velodyne_packets import LAYOUTS, PacketLayout
from graphcal.importers.velodyne_stream import PacketDecoder, VelodyneCapture, all_returns, decoded_returns
from graphcal.importers.velodyne_survey import PacketSurvey, layout
from graphcal.recording.directory import Recording
from graphcal.recording.extrinsic import Extrinsic
from graphcal.recording.points import SCHEMA, PointTable
from graphcal.recording.sensor import CATALOG, SensorModel, sensor_from_catalog
from graphcal.recording.trajectory import Trajectory

_SYNC_TOLERANCE_S = 3.0  # an RMC sentence arrives up to about 2 s after the second it names
_GENERIC_CALIBRATION = {"VLP-32C": "VLP32.yaml", "VLS-128": "VLS128.yaml"}  # the drivers' model files
_ORDER = "data packets in time order (as a capture records them), out of order by less than a chunk of packets"


@dataclass(frozen=True)
class VelodyneReturns(VelodyneCapture):
    """A decoded capture: returns `time_s` (s past the top of the first packet's hour, on the sensor clock,
    float64), `fibre`, `range` [m], `azimuth` [rad, encoder, clockwise], `intensity`, `scan` (revolution index: +1
    at each azimuth wrap, VeloView's frames), sorted by time."""

    returns: dict[str, np.ndarray] = field(default_factory=dict)


@dataclass(frozen=True)
class SurveyedCapture:
    """A surveyed capture (capture: rotation_hz 0 until decoded), its packet layout, and its data packets again,
    chunk by chunk (PACKET arrays, in capture order)."""

    capture: VelodyneCapture
    layout: PacketLayout
    packets: Callable[[], Iterator[np.ndarray]]

    def decoder(self) -> PacketDecoder:
        """A decoder of the packets from the first on."""
        capture = self.capture
        return PacketDecoder(self.layout, capture.dual_return, capture.distance_m, capture.interpolated_azimuth)


def surveyed_capture(survey: PacketSurvey, packets: Callable[[], Iterator[np.ndarray]], *, path: Path,
                     model: str | None = None, distance_resolution_m: float | None = None,
                     interpolate_azimuth: bool = True, **counts) -> SurveyedCapture:
    """The capture the survey describes, with its layout (forced `model` or detected). The distance unit is
    the model's (2 or 4 mm); an HDL-64E's calibration file states its own (db.xml distLSB_), which
    distance_resolution_m passes on. counts: VelodyneCapture's fixes, n_other_packets, cut_bytes."""
    chosen, dual = layout(path, survey, model)
    unit_m = distance_resolution_m if chosen.model == "HDL-64E" and distance_resolution_m else chosen.distance_m
    capture = VelodyneCapture(path=path, model=chosen.model, dual_return=dual, rotation_hz=0.0,
                              interpolated_azimuth=interpolate_azimuth, host_hour_utc_s=survey.host_hour_utc_s,
                              n_data_packets=survey.n_packets, distance_m=unit_m, **counts)
    return SurveyedCapture(capture, chosen, packets)


def decoded_capture(surveyed: SurveyedCapture) -> VelodyneReturns:
    """Every return of a surveyed capture in memory, sorted by time (a capture small enough to hold)."""
    decoder = surveyed.decoder()
    returns = all_returns(decoder, surveyed.packets())
    return VelodyneReturns(**{**surveyed.capture.__dict__, "rotation_hz": decoder.rotation_hz()}, returns=returns)


def write_velodyne_recording(surveyed: SurveyedCapture, out: str | Path, importer: str, *,
                             calibration: VelodyneCalibration | None = None, trajectory: Trajectory | None = None,
                             position: tuple[float, float, float] | None = None,
                             attitude_deg: tuple[float, float, float] = (0.0, 0.0, 0.0),
                             extrinsic: Extrinsic | None = None, extrinsic_note: str | None = None,
                             crs: str = "auto", name: str | None = None) -> Recording:
    """A surveyed capture as the recording folder `out` (written whole or not at all, chunk by chunk), times in GPS
    seconds of week.

    calibration: the unit's db.xml/YAML (required for an HDL-64E, a VLP-32C and a VLS-128), else the catalogue
    model. trajectory: poses on the same clock (e.g. from an SBET), cut to the returns' span +- 1 s; else a static
    trajectory at `position` (lat, lon deg, ellipsoidal height m) or at the mean GPRMC fix (height 0 m), with
    `attitude_deg` (roll, pitch, yaw vs ENU). extrinsic: nominal lidar -> body, identity if None; extrinsic_note:
    where a given one came from, for the notes. What was assumed is listed in `recording.source['notes']`.
    """
    out, capture = Path(out), surveyed.capture
    path = capture.path
    sensor_notes, hour_notes = [], []
    sensor = _sensor(capture, calibration, sensor_notes)  # before the decoding: a missing calibration fails early
    hour_utc_s = _hour(capture, hour_notes)
    where = "the position given"
    if trajectory is None and position is None:
        position, where = _position_of_fixes(capture)
    span_s, week, decoder = [np.inf, -np.inf], None, surveyed.decoder()
    with atomic_directory(out) as folder:
        with return_writer(folder, path, _ORDER, list(SCHEMA)) as returns:
            for decoded in decoded_returns(decoder, surveyed.packets()):
                if len(decoded["time_s"]):
                    time, week = seconds_of_week(hour_utc_s, decoded["time_s"], week)
                    span_s = [min(span_s[0], float(time.min())), max(span_s[1], float(time.max()))]
                    returns.add({"time": time, **{key: decoded[key] for key in SCHEMA if key != "time"}})
        if not returns.n_returns:
            raise RecordingError(path, "no return in the data packets (every distance is 0)",
                                 expected="a capture of a running sensor")
        rotation_hz = decoder.rotation_hz()
        mode = "dual" if capture.dual_return else "single"
        notes = [f"{capture.n_data_packets} {capture.model} data packets ({mode} return), {returns.n_returns} returns, "
                 f"{rotation_hz:.2f} Hz"]
        if capture.n_other_packets:
            notes.append(f"{capture.n_other_packets} other records skipped (neither lidar data nor position packets)")
        if capture.cut_bytes:
            notes.append(f"the capture ends inside a record (cut short): its last {capture.cut_bytes} bytes dropped")
        notes += [*sensor_notes, *hour_notes, f"times are GPS seconds of week {week} (sensor time past the hour + "
                                              "the hour in UTC + leap seconds)"]
        trajectory = capture_trajectory(path, np.array(span_s), week, trajectory, position, attitude_deg, notes, where)
        if extrinsic is None:
            extrinsic = Extrinsic(lever_arm_m=(0.0, 0.0, 0.0), boresight_deg=(0.0, 0.0, 0.0))
            notes.append("nominal extrinsic: identity (lidar frame = body frame)")
        elif extrinsic_note:
            notes.append(extrinsic_note)
        source = {"importer": importer, "file": path.name, "model": capture.model,
                  "time_base": "GPS seconds of week", "gps_week": week,
                  "azimuth": "interpolated to each firing" if capture.interpolated_azimuth else "block azimuth",
                  "notes": notes}
        recording = Recording(name=name or path.stem, crs=crs, sensor=replace(sensor, rotation_hz=rotation_hz),
                              extrinsic=extrinsic, trajectory=trajectory, points=PointTable.open(folder / POINTS),
                              source=source)
        save_imported(recording, folder, path)
    return Recording.load(out, validate=False)


def _sensor(capture: VelodyneCapture, calibration: VelodyneCalibration | None, notes: list[str]) -> SensorModel:
    """The nominal sensor model: the calibration file's, else the catalogue's (rotation_hz left to the caller)."""
    path, model = capture.path, capture.model
    if calibration is None:
        if model == "HDL-64E" or model not in CATALOG:  # per-unit or per-model tables only
            generic = _GENERIC_CALIBRATION.get(model)
            raise RecordingError(path, f"{model} packets and no calibration file",
                                 expected="the unit's db.xml or ROS calibration YAML (--calibration)"
                                          + (f", or the model's generic {generic} of the ROS velodyne driver or "
                                             "nebula" if generic else ""))
        notes.append(f"nominal sensor model: graphcal's {model} catalogue")
        return sensor_from_catalog(model)
    sensor = calibration.sensor
    if sensor.n_fibres != LAYOUTS[model].n_lasers:
        raise RecordingError(calibration.path, f"{sensor.n_fibres} lasers",
                             expected=f"{LAYOUTS[model].n_lasers} lasers for the {model} data of {path.name}")
    notes.append(f"nominal sensor model: {calibration.path.name}")
    notes.extend(calibration.notes())
    if abs(calibration.distance_resolution_m - capture.distance_m) > 1e-9:
        notes.append(f"{calibration.path.name} states a distance resolution of {calibration.distance_resolution_m} m; "
                     f"the {model} packets count in {capture.distance_m} m units (its manual), which are used")
    timing = CATALOG[model].timing if model in CATALOG else None
    return replace(sensor, model=model, timing=timing)


def _hour(capture: VelodyneCapture, notes: list[str]) -> float:
    """The top of the first packet's hour in UTC [s since 1970]: from the GPRMC fixes, else the host clock."""
    valid = [(sensor_s, fix) for sensor_s, fix in capture.fixes if fix.valid]
    if not valid:
        notes.append("no valid $GPRMC fix: the hour of the sensor timestamps is taken from the capture host clock "
                     "(pcap record times, ROS packet stamps); times within the hour are the sensor's")
        return capture.host_hour_utc_s
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


def _position_of_fixes(capture: VelodyneCapture) -> tuple[tuple[float, float, float], str]:
    """The static position of a capture without trajectory or --position: the mean of its valid $GPRMC fixes
    (height 0 m: RMC has none), and where it comes from in words; RecordingError when there is none."""
    fixes = [fix for _, fix in capture.fixes if fix.valid]
    if not fixes:
        raise RecordingError(capture.path, "no trajectory given and no valid $GPRMC fix in the position packets",
                             expected="a position (--position LAT,LON,ALT) or a trajectory (--trajectory)")
    position = (float(np.mean([f.lat_deg for f in fixes])), float(np.mean([f.lon_deg for f in fixes])), 0.0)
    return position, f"the mean of {len(fixes)} GPRMC fixes, height 0 m (RMC has no height)"
