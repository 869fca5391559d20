"""A calibrated sensor model -> Velodyne's db.xml and the ROS velodyne_pointcloud YAML (the export
formats `velodyne-xml` and `ros-yaml`).

Per laser, from the nominal model of sensor.yaml and a calibration's offsets (d_rho, d_theta, d_phi, h_z),
in the velodyne_pointcloud driver's terms (rawdata.cc):

    vert_correction         = e = elevation + d_phi
    rot_correction          = -(azimuth_offset + d_theta)     (Velodyne's azimuth turns clockwise)
    dist_correction         = range_offset + d_rho + Z sin e  (Z = height_offset + h_z)
    vert_offset_correction  = vertical_offset + Z cos e
    horiz_offset_correction = horizontal_offset
    dist_correction_x / _y  = the original's, moved by as much as dist_correction where the laser uses them
                              (the two-point shape kept)

The formats have no per-laser height. The driver computes xy = d cos e - V sin e and z = d sin e + V cos e
(d the corrected distance, V vert_offset_correction); with d + Z sin e and V + Z cos e, xy is unchanged and z
gains Z: the decoded point is the calibrated model's. db.xml holds cm and degrees, the YAML m and radians
(the driver's gen_calibration.py).

Starting from the unit's original file (its text), only the numbers of these fields change, in place: every
other field, the order, the layout, comments and db.xml's DOCTYPE stay as they were, and a value that does
not change keeps its original digits. Without an original, a complete file is written.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import yaml

from graphcal.common.atomic import atomic_path
from graphcal.common.errors import ConfigError
from graphcal.recording.sensor import SensorModel

# the calibrated fields: (ROS YAML key, db.xml tag, factor from m / rad to the db.xml unit)
FIELDS = (("vert_correction", "vertCorrection_", np.degrees(1.0)),
          ("rot_correction", "rotCorrection_", np.degrees(1.0)),
          ("dist_correction", "distCorrection_", 100.0),
          ("vert_offset_correction", "vertOffsetCorrection_", 100.0),
          ("horiz_offset_correction", "horizOffsetCorrection_", 100.0))
TWO_POINT = (("dist_correction_x", "distCorrectionX_"), ("dist_correction_y", "distCorrectionY_"))
UNCHANGED = 1e-9  # file units: a value closer than this to the original's keeps the original's digits
_NOTED_M = 1e-4  # h_z smaller than this is not worth a note
# m per range count of the packets (velodyne_pointcloud's distance_resolution, db.xml's distLSB_ in cm)
DISTANCE_RESOLUTION_M = {"VLS-128": 0.004}
_DEFAULT_RESOLUTION_M = 0.002


def calibrated_fields(sensor: SensorModel, offsets: np.ndarray) -> dict[str, np.ndarray]:
    """{ROS YAML key: per-laser value in m / rad} of the calibrated model (the module's table)."""
    offsets = np.asarray(offsets, dtype=np.float64)
    if offsets.shape != (sensor.n_fibres, 4):
        raise ConfigError(f"offsets of shape {offsets.shape}: expected ({sensor.n_fibres}, 4), one row per fibre")
    if sensor.beam_origin_m != 0.0:
        raise ConfigError(f"the {sensor.model} model has a beam origin ({sensor.beam_origin_m} m from the spin axis): "
                          "the Velodyne formats cannot hold it (export an Ouster unit as ouster-json)")
    elevation = np.radians(sensor.elevation_deg) + offsets[:, 2]
    height = sensor.height_offset_m + offsets[:, 3]
    return {"vert_correction": elevation,
            "rot_correction": -(np.radians(sensor.azimuth_offset_deg) + offsets[:, 1]),
            "dist_correction": sensor.range_offset_m + offsets[:, 0] + height * np.sin(elevation),
            "vert_offset_correction": sensor.vertical_offset_m + height * np.cos(elevation),
            "horiz_offset_correction": np.asarray(sensor.horizontal_offset_m, dtype=np.float64)}


def write_db_xml(path: str | Path, sensor: SensorModel, offsets: np.ndarray, original: str | None = None) -> list[str]:
    """Write the calibrated model as a Velodyne db.xml (the original's text edited, or a complete file)
    to path atomically; returns the notes."""
    fields = {tag: calibrated_fields(sensor, offsets)[key] * scale for key, tag, scale in FIELDS}
    if original is None:
        text, notes = _new_db_xml(sensor, fields), []
    else:
        text, notes = _edited(original, _XmlLasers(original, sensor.n_fibres), fields, "distCorrection_",
                              [tag for _, tag in TWO_POINT], lambda v: f"{v:.8g}")
    _write(path, text)
    return notes + _height_notes(offsets)


def write_ros_yaml(path: str | Path, sensor: SensorModel, offsets: np.ndarray, original: str | None = None) -> list[str]:
    """Write the calibrated model as a ROS velodyne_pointcloud calibration YAML (the original's text edited,
    or a complete file) to path atomically; returns the notes."""
    fields = calibrated_fields(sensor, offsets)
    if original is None:
        text, notes = _new_ros_yaml(sensor, fields), []
    else:
        text, notes = _edited(original, _YamlLasers(original, sensor.n_fibres), fields, "dist_correction",
                              [key for key, _ in TWO_POINT], repr)
        _check_yaml(text, fields)
    _write(path, text)
    if sensor.model == "VLS-128" and np.abs(fields["dist_correction"]).max() + np.abs(
            fields["vert_offset_correction"]).max() > _NOTED_M:
        notes.append("velodyne_pointcloud decodes VLS-128 packets without dist_correction and "
                      "vert_offset_correction: the range and height offsets written are not applied by that driver")
    return notes + _height_notes(offsets)


def _write(path: str | Path, text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def _height_notes(offsets: np.ndarray) -> list[str]:
    largest = float(np.abs(np.asarray(offsets)[:, 3]).max())
    if largest <= _NOTED_M:
        return []
    return [f"the format has no per-laser height: h_z (largest {largest * 1000:.1f} mm) went into the distance and "
            "vertical offset corrections (+h_z sin e, +h_z cos e), which decode to the same points"]


# --- editing the original's text --------------------------------------------------------------------------
class _XmlLasers:
    """Where each laser's <px> entry is in a db.xml's text, and its fields."""

    def __init__(self, text: str, n_fibres: int):
        try:
            ET.fromstring(text.encode("utf-8"))
        except ET.ParseError as error:
            raise ConfigError(f"the original db.xml is not valid XML: {error}") from None
        self.spans = {}
        for match in re.finditer(r"<px\b[^>]*>(.*?)</px>", text, re.S):
            laser = re.search(r"<id_>\s*(\d+)\s*</id_>", match.group(1))
            if laser is not None:
                self.spans[int(laser.group(1))] = match.span(1)
        _all_lasers(self.spans, n_fibres, "db.xml", "points_ <px> entries with <id_>")

    mm = 10.0  # per file unit (cm)

    @staticmethod
    def field(body: str, tag: str) -> re.Match | None:
        return re.search(rf"<{tag}>\s*([^<\s]*)\s*</{tag}>", body)

    def uses_two_point(self, body: str, laser: int) -> bool:
        """gen_calibration.py's rule: distCorrectionX_ and distCorrectionY_ both nonzero."""
        values = [(tag, self.field(body, tag)) for _, tag in TWO_POINT]
        return all(v is not None and _float(v.group(1), tag, laser) != 0.0 for tag, v in values)

    @staticmethod
    def insert(body: str, tag: str, value: str) -> str:
        raise ConfigError(f"the original db.xml's laser entries have no <{tag}> to hold the calibrated value "
                          "(an older db.xml version): export without --from")


class _YamlLasers:
    """Where each laser's entry of the `lasers:` list is in a ROS calibration YAML's text, and its fields."""

    def __init__(self, text: str, n_fibres: int):
        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError as error:
            raise ConfigError(f"the original ROS calibration is not valid YAML: {str(error).splitlines()[0]}") from None
        if not isinstance(data, dict) or not isinstance(data.get("lasers"), list):
            raise ConfigError("the original ROS calibration has no 'lasers' list")
        head = re.search(r"^lasers[ \t]*:[ \t]*(#.*)?\r?\n", text, re.M)
        if head is None:
            raise ConfigError("the original ROS calibration's lasers are not a block list ('lasers:' at the top, then "
                              "one '- ' entry per laser): export without --from")
        lines = [(m.start(), m.group(1), m.group(2)) for m in re.finditer(r"^([ \t]*)(\S?.*)$", text[head.end():], re.M)]
        self.spans, dash, start = {}, None, None
        for offset, indent, rest in lines + [(len(text) - head.end(), "", "end")]:
            offset += head.end()
            if not rest or rest.startswith("#"):
                continue
            if dash is None:
                if not rest.startswith("-"):
                    break
                dash = len(indent)
            if len(indent) <= dash:
                if start is not None:
                    self._add(text[start:offset], start)
                start = offset if len(indent) == dash and rest.startswith("-") else None
                if start is None:
                    break
        _all_lasers(self.spans, n_fibres, "ROS calibration", "'lasers' entries with laser_id")

    def _add(self, entry: str, start: int) -> None:
        laser = self.field(entry, "laser_id")
        if laser is not None and laser.group(1).isdigit():
            end = len(entry.rstrip())
            self.spans[int(laser.group(1))] = (start, start + end)

    mm = 1000.0  # per file unit (m)

    @staticmethod
    def field(body: str, key: str) -> re.Match | None:
        return re.search(rf"(?<![\w]){key}[ \t]*:[ \t]*([^,}}\s#]+)", body)

    def uses_two_point(self, body: str, laser: int) -> bool:
        """velodyne_pointcloud's rule: two_pt_correction_available true."""
        flag = self.field(body, "two_pt_correction_available")
        return flag is not None and flag.group(1).lower() == "true"

    @staticmethod
    def insert(body: str, key: str, value: str) -> str:
        if body.endswith("}"):  # flow mapping: before its closing brace
            return f"{body[:-1].rstrip()}, {key}: {value}}}"
        dash = re.match(r"([ \t]*)-([ \t]*)", body)
        newline = "\r\n" if "\r\n" in body else "\n"
        return f"{body}{newline}{dash.group(1)} {dash.group(2)}{key}: {value}"


def _all_lasers(spans: dict, n_fibres: int, what: str, expected: str) -> None:
    missing = [i for i in range(n_fibres) if i not in spans]
    if missing:
        raise ConfigError(f"the original {what} has no laser {missing[0]}: expected {expected} 0..{n_fibres - 1}, "
                          "one per fibre of the calibrated sensor")


def _edited(text: str, lasers, fields: dict[str, np.ndarray], distance: str, two_point: list[str],
            number) -> tuple[str, list[str]]:
    """text with each laser's fields set to `fields` (file units), written by number(); the two_point fields
    moved by as much as the distance field. Values within UNCHANGED of the original keep its digits."""
    edits, moved = [], 0.0
    for laser, (start, end) in sorted(lasers.spans.items()):
        if laser >= len(fields[distance]):
            continue
        body = text[start:end]
        new_body, shift = body, 0.0
        for key, values in list(fields.items()) + [(key, None) for key in two_point]:
            match = lasers.field(new_body, key)
            old = None if match is None else _float(match.group(1), key, laser)
            if values is None:  # a two-point correction in use: the original's, moved with the distance correction
                if match is None or shift == 0.0 or not lasers.uses_two_point(body, laser):
                    continue
                value = old + shift
                moved = max(moved, abs(shift))
            else:
                value = float(values[laser])
            if key == distance:
                shift = 0.0 if old is None else value - old
            if old is not None and abs(value - old) <= UNCHANGED:
                continue
            if match is None:
                if abs(value) > UNCHANGED:
                    new_body = lasers.insert(new_body, key, number(value))
                continue
            new_body = new_body[:match.start(1)] + number(value) + new_body[match.end(1):]
        edits.append((start, end, new_body))
    for start, end, body in reversed(edits):
        text = text[:start] + body + text[end:]
    notes = [f"the two-point range corrections ({', '.join(two_point)}) moved with the distance correction (by up "
             f"to {moved * lasers.mm:.1f} mm), keeping their shape"] if moved > UNCHANGED else []
    return text, notes


def _float(text: str, key: str, laser: int) -> float:
    try:
        return float(text)
    except ValueError:
        raise ConfigError(f"the original's {key} of laser {laser} is {text!r}: expected a number") from None


def _check_yaml(text: str, fields: dict[str, np.ndarray]) -> None:
    """The edited YAML read back holds the calibrated values (else its layout defeated the edit)."""
    lasers = {row.get("laser_id"): row for row in yaml.safe_load(text)["lasers"] if isinstance(row, dict)}
    for key, values in fields.items():
        written = np.array([float(lasers[i].get(key, 0.0)) for i in range(len(values))])
        if not np.allclose(written, values, rtol=0.0, atol=10 * UNCHANGED):
            raise ConfigError(f"the original ROS calibration's layout could not be edited ({key} did not take the "
                              "calibrated values): export without --from")


# --- complete files -------------------------------------------------------------------------------------
def _resolution_m(sensor: SensorModel) -> float:
    return DISTANCE_RESOLUTION_M.get(sensor.model, _DEFAULT_RESOLUTION_M)


def _new_ros_yaml(sensor: SensorModel, fields: dict[str, np.ndarray]) -> str:
    """Every key velodyne_pointcloud's calibration reader asks for, one laser per row (gen_calibration.py's)."""
    lasers = []
    for i in range(sensor.n_fibres):
        row = {key: float(values[i]) for key, values in fields.items()}
        row |= {"dist_correction_x": row["dist_correction"], "dist_correction_y": row["dist_correction"],
                "two_pt_correction_available": False, "focal_distance": 0.0, "focal_slope": 0.0,
                "min_intensity": 0, "max_intensity": 255, "laser_id": i}
        lasers.append(dict(sorted(row.items())))
    header = f"# {sensor.model} calibrated by graphcal (velodyne_pointcloud calibration: m, rad)\n"
    return header + yaml.safe_dump({"distance_resolution": _resolution_m(sensor), "lasers": lasers,
                                    "num_lasers": sensor.n_fibres}, sort_keys=False, default_flow_style=None)


def _new_db_xml(sensor: SensorModel, fields: dict[str, np.ndarray]) -> str:
    """A complete boost_serialization db.xml as Velodyne's tools write it (64 slots at least, the unused
    ones disabled)."""
    n, slots = sensor.n_fibres, max(64, sensor.n_fibres)

    def items(values, indent="\t\t") -> str:
        return "".join(f"{indent}<item>{v}</item>\n" for v in values)

    def block(tag: str, values, version: bool, attributes: str = "") -> str:
        return (f"\t<{tag}{attributes}>\n\t\t<count>{slots}</count>\n" + ("\t\t<item_version>0</item_version>\n"
                if version else "") + items(values) + f"\t</{tag}>\n")

    first_color = ' class_id="4" tracking_level="0" version="0"'
    colors = "".join(f"\t\t<item{first_color if i == 0 else ''}>\n\t\t\t<rgb>\n"
                     f"\t\t\t\t<count>3</count>\n{items((1, 1, 1), chr(9) * 4)}\t\t\t</rgb>\n\t\t</item>\n"
                     for i in range(slots))
    points = []
    for i in range(slots):
        head = ('<item class_id="8" tracking_level="0" version="1">', '<px class_id="9" tracking_level="1" '
                'version="1" object_id="_1">') if i == 0 else ("<item>", f'<px class_id_reference="9" object_id="_{i + 1}">')
        values = {tag: (float(fields[tag][i]) if i < n else 0.0) for _, tag, _ in FIELDS}
        values |= {tag: values["distCorrection_"] for _, tag in TWO_POINT}
        values |= {"focalDistance_": 0, "focalSlope_": 0}
        order = ("rotCorrection_", "vertCorrection_", "distCorrection_", "distCorrectionX_", "distCorrectionY_",
                 "vertOffsetCorrection_", "horizOffsetCorrection_", "focalDistance_", "focalSlope_")
        body = "".join(f"\t\t\t\t<{tag}>{values[tag]:.8g}</{tag}>\n" for tag in order)
        points.append(f"\t\t{head[0]}\n\t\t\t{head[1]}\n\t\t\t\t<id_>{i}</id_>\n{body}\t\t\t</px>\n\t\t</item>\n")
    return ('<?xml version="1.0" encoding="UTF-8" standalone="yes" ?>\n<!DOCTYPE boost_serialization>\n'
            '<boost_serialization signature="serialization::archive" version="4">\n'
            f'<DB class_id="0" tracking_level="1" version="0" object_id="_0">\n'
            f"\t<distLSB_>{_resolution_m(sensor) * 100:g}</distLSB_>\n"
            '\t<position_ class_id="1" tracking_level="0" version="0">\n\t\t<xyz>\n\t\t\t<count>3</count>\n'
            f"{items((0, 0, 0), chr(9) * 3)}\t\t</xyz>\n\t</position_>\n"
            '\t<orientation_ class_id="2" tracking_level="0" version="0">\n\t\t<rpy>\n\t\t\t<count>3</count>\n'
            f"{items((0, 0, 0), chr(9) * 3)}\t\t</rpy>\n\t</orientation_>\n"
            f'\t<colors_ class_id="3" tracking_level="0" version="0">\n\t\t<count>{slots}</count>\n'
            f"\t\t<item_version>0</item_version>\n{colors}\t</colors_>\n"
            + block("enabled_", [int(i < n) for i in range(slots)], False)
            + block("intensity_", [0] * slots, False)
            + block("minIntensity_", [0] * slots, True)
            + block("maxIntensity_", [255] * slots, True)
            + f'\t<points_ class_id="7" tracking_level="0" version="0">\n\t\t<count>{slots}</count>\n'
            f"\t\t<item_version>1</item_version>\n{''.join(points)}\t</points_>\n</DB>\n</boost_serialization>\n")
