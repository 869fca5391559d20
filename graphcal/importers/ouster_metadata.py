"""Ouster sensor metadata JSON (the unit's factory beam intrinsics and lidar data format).

Reads both layouts the sensors and ouster-sdk write: the flat one of firmware 2.0-2.3
(`beam_altitude_angles`, `data_format`, ... at the top) and the sectioned one of later firmware
(`beam_intrinsics`, `lidar_intrinsics`, `lidar_data_format`, `config_params`, `sensor_info`).
Angles in degrees, lengths in millimetres as in the file; `sensor_model` converts to graphcal's
sensor.yaml (metres, Velodyne azimuth convention).

Geometry (Ouster sensor docs, "Lidar Range to XYZ"; ouster-sdk `make_xyz_lut`): for range r of
beam i in measurement column m of W,
    theta_e = 2 pi (1 - m / W), theta_a = -beam_azimuth_angles[i], phi = beam_altitude_angles[i],
    p_lidar = (r - n) (cos(theta_e + theta_a) cos phi, sin(theta_e + theta_a) cos phi, sin phi)
              + (n_x cos theta_e, n_x sin theta_e, n_z)
with (n_x, n_z) the translation of beam_to_lidar_transform (n_x = lidar_origin_to_beam_origin_mm
when the file has no such transform) and n = sqrt(n_x^2 + n_z^2); then
p_sensor = lidar_to_sensor_transform * p_lidar.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from graphcal.common.errors import RecordingError
from graphcal.recording.sensor import SensorModel

# field -> section of the sectioned layout (the flat layout has them at the top)
SECTIONS = {"beam_altitude_angles": "beam_intrinsics", "beam_azimuth_angles": "beam_intrinsics",
            "lidar_origin_to_beam_origin_mm": "beam_intrinsics", "beam_to_lidar_transform": "beam_intrinsics",
            "lidar_to_sensor_transform": "lidar_intrinsics", "lidar_mode": "config_params",
            "udp_port_lidar": "config_params", "prod_line": "sensor_info", "prod_sn": "sensor_info"}
_FORMAT_FLAT, _FORMAT_SECTIONED = "data_format", "lidar_data_format"
PROFILES = ("LEGACY", "RNG19_RFL8_SIG16_NIR16", "RNG15_RFL8_NIR8")


@dataclass(frozen=True)
class OusterMetadata:
    """One unit's metadata. Angles [deg], transforms 4x4 with translations [mm], as in the file.

    raw: the parsed JSON as it is (the export writes it back with corrected beam angles).
    """

    path: Path
    raw: dict
    prod_line: str
    columns_per_frame: int
    columns_per_packet: int
    pixels_per_column: int
    column_window: tuple[int, int]
    udp_profile_lidar: str
    udp_port_lidar: int
    rotation_hz: float
    altitude_deg: np.ndarray
    azimuth_deg: np.ndarray
    beam_to_lidar: np.ndarray
    lidar_to_sensor: np.ndarray

    @property
    def sectioned(self) -> bool:
        return "beam_intrinsics" in self.raw

    def sensor_model(self) -> SensorModel:
        """The factory beam model in graphcal's sensor.yaml, in the Ouster *lidar* frame (the
        lidar-to-sensor transform goes to the extrinsic). Azimuth = 2 pi m / W clockwise, so
        azimuth_offset_deg = beam_azimuth_angles; B = n_x; the rest of n comes off the range
        (range_offset_m = (n_x - n) / 1000) and n_z is a height (height_offset_m)."""
        n_x, n_z = self.beam_to_lidar[0, 3], self.beam_to_lidar[2, 3]
        n = math.hypot(n_x, n_z)
        count = len(self.altitude_deg)
        return SensorModel(model=self.prod_line, rotation_hz=self.rotation_hz,
                           reference_fibre=int(np.argmin(np.abs(self.altitude_deg))),
                           elevation_deg=self.altitude_deg.copy(), azimuth_offset_deg=self.azimuth_deg.copy(),
                           range_offset_m=np.full(count, (n_x - n) / 1000.0), vertical_offset_m=np.zeros(count),
                           horizontal_offset_m=np.zeros(count), height_offset_m=np.full(count, n_z / 1000.0),
                           beam_origin_m=n_x / 1000.0)


def field(raw: dict, name: str, default=None):
    """A field of either layout (`default` when the file has none)."""
    section = raw.get(SECTIONS.get(name, ""), {})
    if isinstance(section, dict) and name in section:
        return section[name]
    return raw.get(name, default)


def read_ouster_metadata(path: str | Path) -> OusterMetadata:
    """Parse and check an Ouster metadata JSON; RecordingError naming the field for bad input."""
    path = Path(path)
    if not path.is_file():
        raise RecordingError(path, "file not found", expected="the sensor's metadata JSON")
    try:
        raw = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as error:
        raise RecordingError(path, f"not JSON ({error})", expected="the sensor's metadata JSON") from None
    if not isinstance(raw, dict):
        raise RecordingError(path, "not a JSON object", expected="the sensor's metadata JSON")
    altitude = _angles(path, raw, "beam_altitude_angles", -90.0, 90.0)
    azimuth = _angles(path, raw, "beam_azimuth_angles", -180.0, 180.0)
    if len(azimuth) != len(altitude):
        raise RecordingError(path, f"{len(azimuth)} beam azimuths for {len(altitude)} altitudes",
                             field="beam_azimuth_angles", expected="one azimuth per beam")
    data_format = raw.get(_FORMAT_SECTIONED, raw.get(_FORMAT_FLAT, {}))
    if not isinstance(data_format, dict):
        raise RecordingError(path, f"{data_format!r}", field=_FORMAT_FLAT, expected="an object")
    mode = field(raw, "lidar_mode")
    columns, rotation_hz = _lidar_mode(path, mode)
    pixels = _integer(path, data_format.get("pixels_per_column", len(altitude)), "pixels_per_column", 1)
    if pixels != len(altitude):
        raise RecordingError(path, f"{pixels} pixels per column for {len(altitude)} beams",
                             field="pixels_per_column", expected="one pixel per beam")
    columns = _integer(path, data_format.get("columns_per_frame", columns), "columns_per_frame", 1)
    window = data_format.get("column_window", [0, columns - 1])
    if (not isinstance(window, list) or len(window) != 2
            or not all(isinstance(v, int) and 0 <= v < columns for v in window)):
        raise RecordingError(path, f"column_window {window!r}", field="column_window",
                             expected=f"two column indices in 0..{columns - 1}")
    profile = data_format.get("udp_profile_lidar", field(raw, "udp_profile_lidar", "LEGACY"))
    if profile not in PROFILES:
        raise RecordingError(path, f"udp_profile_lidar {profile!r}", field="udp_profile_lidar",
                             expected=f"one of {', '.join(PROFILES)} (single-return profiles)")
    beam_to_lidar = field(raw, "beam_to_lidar_transform")
    if beam_to_lidar is None:
        origin = _number(path, field(raw, "lidar_origin_to_beam_origin_mm"), "lidar_origin_to_beam_origin_mm")
        beam_to_lidar = np.eye(4)
        beam_to_lidar[0, 3] = origin
    else:
        beam_to_lidar = _transform(path, beam_to_lidar, "beam_to_lidar_transform")
    prod_line = field(raw, "prod_line")
    if not isinstance(prod_line, str) or not prod_line:
        raise RecordingError(path, f"prod_line {prod_line!r}", field="prod_line", expected="the product line, e.g. OS-1-128")
    return OusterMetadata(path=path, raw=raw, prod_line=prod_line, columns_per_frame=columns,
                          columns_per_packet=_integer(path, data_format.get("columns_per_packet", 16),
                                                      "columns_per_packet", 1),
                          pixels_per_column=pixels, column_window=(window[0], window[1]), udp_profile_lidar=profile,
                          udp_port_lidar=_integer(path, field(raw, "udp_port_lidar", 7502), "udp_port_lidar", 0),
                          rotation_hz=rotation_hz, altitude_deg=altitude, azimuth_deg=azimuth,
                          beam_to_lidar=beam_to_lidar,
                          lidar_to_sensor=_transform(path, field(raw, "lidar_to_sensor_transform"),
                                                     "lidar_to_sensor_transform"))


def _angles(path: Path, raw: dict, name: str, low: float, high: float) -> np.ndarray:
    values = field(raw, name)
    if not isinstance(values, list) or not values:
        raise RecordingError(path, "missing or empty", field=name, expected="a list of angles in degrees, one per beam")
    for i, value in enumerate(values):
        number = _number(path, value, f"{name}[{i}]")
        if not low <= number <= high:
            raise RecordingError(path, f"{number}", field=f"{name}[{i}]", expected=f"an angle within {low}..{high} deg")
    return np.asarray(values, dtype=np.float64)


def _number(path: Path, value, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise RecordingError(path, f"value {value!r}", field=name, expected="a finite number")
    return float(value)


def _integer(path: Path, value, name: str, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise RecordingError(path, f"value {value!r}", field=name, expected=f"an integer >= {minimum}")
    return value


def _lidar_mode(path: Path, mode) -> tuple[int, float]:
    """'1024x10' -> (1024 columns, 10.0 Hz)."""
    try:
        columns, rate = (int(part) for part in str(mode).split("x"))
    except ValueError:
        columns = rate = 0
    if columns <= 0 or rate <= 0:
        raise RecordingError(path, f"lidar_mode {mode!r}", field="lidar_mode", expected="COLUMNSxHZ, e.g. 1024x10")
    return columns, float(rate)


def _transform(path: Path, values, name: str) -> np.ndarray:
    """A 4x4 row-major transform (16 numbers); its rotation must be a rotation."""
    if not isinstance(values, list) or len(values) != 16:
        raise RecordingError(path, f"{values!r}"[:60], field=name, expected="16 numbers (a 4x4 row-major transform)")
    matrix = np.array([_number(path, v, f"{name}[{i}]") for i, v in enumerate(values)]).reshape(4, 4)
    rotation = matrix[:3, :3]
    if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-6) or np.linalg.det(rotation) < 0 \
            or not np.allclose(matrix[3], [0, 0, 0, 1]):
        raise RecordingError(path, "not a rigid transform", field=name,
                             expected="a rotation (orthonormal, det +1) and a translation in mm, last row 0 0 0 1")
    return matrix
