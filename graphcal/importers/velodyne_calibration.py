"""Velodyne calibration files -> graphcal's nominal SensorModel (sensor.yaml).

Two formats: Velodyne's db.xml (boost serialization: angles in degrees, lengths in cm) and the
ROS velodyne_pointcloud YAML (`lasers:` list: angles in radians, lengths in m). Per laser, the
geometric terms map onto the factory terms of docs/concepts.md "Frames and names":

    elevation_deg = vertCorrection            azimuth_offset_deg = -rotCorrection
    range_offset_m = distCorrection           vertical_offset_m = vertOffsetCorrection
    horizontal_offset_m = horizOffsetCorrection

This is the velodyne_pointcloud / velodyne-decoder formula (tests/test_importers_velodyne.py
checks it against velodyne-decoder's output). Not carried: the HDL-64E two-point range
correction (distCorrectionX/Y, a range correction that varies with |x| and |y| between 2.4 and
25 m) and the intensity terms (focal distance and slope, min/max intensity). `notes()` says how
large the dropped two-point correction is for the file at hand.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from graphcal.common.errors import RecordingError, finite_number
from graphcal.recording.sensor import CATALOG, OPTIONAL_FIBRE_FIELDS, SensorModel
from graphcal.common.yamlfile import read_yaml

MODEL_BY_LASERS = {16: "VLP-16", 64: "HDL-64E", 128: "VLS-128"}  # 32 lasers: HDL-32E or VLP-32C (model=...)
# (db.xml tag, ROS YAML key, sensor.yaml column, factor to graphcal units from db.xml / from YAML)
_TERMS = (("vertCorrection_", "vert_correction", "elevation_deg", 1.0, np.degrees(1.0)),
          ("rotCorrection_", "rot_correction", "azimuth_offset_deg", -1.0, -np.degrees(1.0)),
          ("distCorrection_", "dist_correction", "range_offset_m", 0.01, 1.0),
          ("vertOffsetCorrection_", "vert_offset_correction", "vertical_offset_m", 0.01, 1.0),
          ("horizOffsetCorrection_", "horiz_offset_correction", "horizontal_offset_m", 0.01, 1.0))
_TWO_POINT = (("distCorrectionX_", "dist_correction_x"), ("distCorrectionY_", "dist_correction_y"))


@dataclass(frozen=True)
class VelodyneCalibration:
    """A calibration file read: the nominal model, the distance unit of the packets [m], and the
    largest two-point range correction the model drops [m] (0 when the file has none)."""

    sensor: SensorModel
    distance_resolution_m: float
    dropped_two_point_m: float
    path: Path

    def notes(self) -> list[str]:
        if self.dropped_two_point_m == 0.0:
            return []
        return [(f"{self.path.name}: the two-point range correction (distCorrectionX/Y, up to "
                 f"{100 * self.dropped_two_point_m:.1f} cm away from distCorrection) is not part of graphcal's "
                 "sensor model and was dropped; the per-fibre range offsets the calibration estimates absorb "
                 "its mean")]


def read_velodyne_calibration(path: str | Path, model: str | None = None) -> VelodyneCalibration:
    """Read a db.xml (.xml) or ROS velodyne YAML (.yaml/.yml) file. model: sensor name, else from the laser count."""
    path = Path(path)
    if not path.is_file():
        raise RecordingError(path, "file not found")
    if path.suffix.lower() == ".xml":
        rows, resolution = _read_db_xml(path)
    elif path.suffix.lower() in (".yaml", ".yml"):
        rows, resolution = _read_ros_yaml(path)
    else:
        raise RecordingError(path, f"suffix {path.suffix!r}", expected="a Velodyne db.xml (.xml) or ROS velodyne "
                                                                       "calibration (.yaml)")
    n = len(rows)
    model = model or MODEL_BY_LASERS.get(n, f"Velodyne-{n}")
    if model in CATALOG and CATALOG[model].n_fibres != n:
        raise RecordingError(path, f"{n} lasers", expected=f"{CATALOG[model].n_fibres} lasers for a {model}")
    columns = {name: np.array([row.get(name, 0.0) for row in rows]) for name in ("elevation_deg",) + OPTIONAL_FIBRE_FIELDS}
    two_point = max((row["two_point_m"] for row in rows), default=0.0)
    sensor = SensorModel(model=model, rotation_hz=10.0, reference_fibre=int(np.argmin(np.abs(columns["elevation_deg"]))),
                         timing=CATALOG[model].timing if model in CATALOG else None, **columns)
    return VelodyneCalibration(sensor, resolution, two_point, path)


def _read_db_xml(path: Path) -> tuple[list[dict], float]:
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as error:
        raise RecordingError(path, f"not valid XML: {error}") from None
    db = root.find("DB")
    if db is None or db.find("points_") is None:
        raise RecordingError(path, "no DB/points_ element", expected="a Velodyne db.xml calibration")
    resolution = 0.01 * _xml_number(path, db, "distLSB_", default=0.2)
    items = db.find("enabled_").findall("item") if db.find("enabled_") is not None else []
    enabled = [int(_number(path, item.text, "enabled_", row)) for row, item in enumerate(items)]
    lasers = {}
    for index, item in enumerate(db.find("points_").findall("item")):
        px = item.find("px")
        if px is None:
            raise RecordingError(path, "item without px", field="points_", row=index, expected="a <px> laser entry")
        laser = int(_xml_number(path, px, "id_", row=index))
        row = {column: scale * _xml_number(path, px, tag, row=index, default=0.0 if tag != "vertCorrection_" else None)
               for tag, _, column, scale, _ in _TERMS}
        row["two_point_m"] = _two_point(row["range_offset_m"], [0.01 * _xml_number(path, px, tag, row=index, default=None)
                                                                for tag, _ in _TWO_POINT if px.find(tag) is not None])
        lasers[laser] = row
    n = sum(enabled) if enabled else len(lasers)
    if enabled and any(enabled[n:]) or any(i not in lasers for i in range(n)):
        raise RecordingError(path, f"enabled lasers {[i for i, on in enumerate(enabled) if on]}", field="enabled_",
                             expected=f"lasers 0..{n - 1} enabled and present in points_")
    return [lasers[i] for i in range(n)], resolution


def _xml_number(path: Path, element, tag: str, row: int | None = None, default: float | None = None) -> float:
    child = element.find(tag)
    return _number(path, None if child is None else child.text, tag, row, default)


def _number(path: Path, text: str | None, field: str, row: int | None = None, default: float | None = None) -> float:
    """The number an XML element's text holds; RecordingError naming the field and row if none."""
    if text is None:
        if default is None:
            raise RecordingError(path, "missing value", field=field, row=row, expected="a number")
        return default
    try:
        return finite_number(float(text), path, field)
    except ValueError:
        raise RecordingError(path, f"value {text!r}", field=field, row=row, expected="a number") from None


def _read_ros_yaml(path: Path) -> tuple[list[dict], float]:
    data = read_yaml(path)
    if not isinstance(data, dict) or not isinstance(data.get("lasers"), list) or not data["lasers"]:
        raise RecordingError(path, "no 'lasers' list", field="lasers", expected="a ROS velodyne calibration")
    resolution = finite_number(data.get("distance_resolution", 0.002), path, "distance_resolution")
    lasers = {}
    for index, laser in enumerate(data["lasers"]):
        if not isinstance(laser, dict) or "laser_id" not in laser or "vert_correction" not in laser:
            raise RecordingError(path, f"entry {laser!r}", field="lasers", row=index,
                                 expected="a mapping with laser_id and vert_correction")
        row = {column: scale * finite_number(laser.get(key, 0.0), path, f"lasers[{index}].{key}")
               for _, key, column, _, scale in _TERMS}
        two_point = [finite_number(laser[key], path, f"lasers[{index}].{key}") for _, key in _TWO_POINT
                     if laser.get("two_pt_correction_available") and key in laser]
        row["two_point_m"] = _two_point(row["range_offset_m"], two_point)
        if not isinstance(laser["laser_id"], int) or isinstance(laser["laser_id"], bool):
            raise RecordingError(path, f"laser_id {laser['laser_id']!r}", field="laser_id", row=index,
                                 expected="an integer")
        lasers[laser["laser_id"]] = row
    if sorted(lasers) != list(range(len(lasers))):
        raise RecordingError(path, f"laser ids {sorted(lasers)}", field="laser_id",
                             expected=f"ids 0..{len(lasers) - 1}, each once")
    return [lasers[i] for i in range(len(lasers))], resolution


def _two_point(range_offset_m: float, corrections: list[float]) -> float:
    """How far the two-point corrections move the range from distCorrection [m] (0 if absent or all zero)."""
    corrections = [c for c in corrections if c != 0.0]
    return max((abs(c - range_offset_m) for c in corrections), default=0.0)
