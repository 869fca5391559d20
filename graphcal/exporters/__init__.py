"""Exporters: a calibration's intrinsics -> the vendor's own calibration file (`graphcal export`).

WRITERS maps each format name to its writer, all of one shape: writer(path, sensor, offsets, original)
-> notes, with sensor the recording's nominal model, offsets (n_fibres, 4) in (m, rad, rad, m) and
original the unit's file as read_original() gives it (None: a complete file is written).
docs/howto/export-calibration.md says which fields change and how.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from graphcal.calibration.observability import INTRINSIC_NAMES  # calibration.yaml's names, in offset order
from graphcal.common.errors import ConfigError, RecordingError
from graphcal.exporters.velodyne_calibration import write_db_xml, write_ros_yaml
from graphcal.importers.ouster_json import write_ouster_json
from graphcal.recording.sensor import SensorModel

WRITERS = {"velodyne-xml": write_db_xml, "ros-yaml": write_ros_yaml, "ouster-json": write_ouster_json}
SUFFIXES = {"velodyne-xml": (".xml",), "ros-yaml": (".yaml", ".yml"), "ouster-json": (".json",)}
SAME_UNIT_DEG = 1.0  # an original whose elevations differ more from the recording's is another model's file
_NOMINAL_TOLERANCE = (1e-5, 1e-4)  # m, deg: the original's fields further from the nominal model are noted


def exported_offsets(offsets: np.ndarray, unobservable: tuple[str, ...], held: tuple[str, ...]) -> tuple[np.ndarray, list[str]]:
    """The offsets to export: those of the intrinsic parameters the calibration named unobservable or held set
    to zero (their nominal values), and a note naming them."""
    offsets = np.array(offsets, dtype=np.float64)
    kept = []
    for name in sorted(set(unobservable) | set(held)):
        fibre, _, parameter = name.partition(".")
        if fibre.startswith("fibre_") and fibre[6:].isdigit() and parameter in INTRINSIC_NAMES \
                and int(fibre[6:]) < len(offsets):
            offsets[int(fibre[6:]), INTRINSIC_NAMES.index(parameter)] = 0.0
            kept.append(name)
    if not kept:
        return offsets, []
    shown = ", ".join(kept[:8]) + (f" and {len(kept) - 8} more" if len(kept) > 8 else "")
    return offsets, [f"{len(kept)} intrinsic parameter(s) the calibration named unobservable or held keep their "
                     f"nominal values (zero offset): {shown}"]


def read_original(export_format: str, path: Path, sensor: SensorModel) -> tuple[object, list[str]]:
    """The unit's original file as WRITERS[export_format] takes it, and notes; ConfigError naming the file when
    it is not a file of this format for the calibrated sensor's model and fibre count."""
    if path.suffix.lower() not in SUFFIXES[export_format]:
        raise ConfigError(f"--from {path}: expected the unit's {' or '.join(SUFFIXES[export_format])} file for "
                          f"--format {export_format}")
    if export_format == "ouster-json":
        from graphcal.importers.ouster_metadata import read_ouster_metadata

        metadata = read_ouster_metadata(path)
        beams = len(metadata.sensor_model().elevation_deg)
        if metadata.prod_line != sensor.model or beams != sensor.n_fibres:
            raise ConfigError(f"--from {path}: prod_line {metadata.prod_line} with {beams} beams; the run's sensor is "
                              f"a {sensor.model} with {sensor.n_fibres} fibres (expected the calibrated unit's file)")
        return metadata.raw, []
    from graphcal.importers.velodyne_calibration import read_velodyne_calibration

    unit = read_velodyne_calibration(path).sensor
    if unit.n_fibres != sensor.n_fibres:
        raise ConfigError(f"--from {path}: {unit.n_fibres} lasers; the run's sensor is a {sensor.model} with "
                          f"{sensor.n_fibres} fibres (expected the calibrated unit's file)")
    apart = np.abs(unit.elevation_deg - sensor.elevation_deg)
    if apart.max() > SAME_UNIT_DEG:
        raise ConfigError(f"--from {path}: laser {int(apart.argmax())}'s elevation is {apart.max():.2f} deg from the "
                          f"run's {sensor.model} nominal model (expected the calibrated unit's file, not another "
                          "model's)")
    try:
        text = path.read_bytes().decode("utf-8")  # its line endings as they are
    except UnicodeDecodeError as error:
        raise RecordingError(path, f"not a UTF-8 text file (byte {error.start})") from None
    return text, _differences(path, unit, sensor)


def _differences(path: Path, unit: SensorModel, sensor: SensorModel) -> list[str]:
    """A note when the original's geometry is not the recording's nominal model (the recording was not imported
    with this file): the file written holds the nominal model plus the calibration."""
    differing = [name for name in ("elevation_deg", "azimuth_offset_deg", "range_offset_m", "vertical_offset_m",
                                   "horizontal_offset_m")
                 if np.abs(getattr(unit, name) - getattr(sensor, name)).max()
                 > _NOMINAL_TOLERANCE[name.endswith("_deg")]]
    if not differing:
        return []
    return [f"{path.name}'s {', '.join(differing)} differ from the recording's nominal model (sensor.yaml): the file "
            "written holds the nominal model plus the calibration in these fields"]
