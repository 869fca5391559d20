"""A calibrated sensor model -> Ouster metadata JSON (the export format `ouster-json`).

Starting from the unit's original metadata (flat or sectioned layout), only the beam angles
change: beam_altitude_angles = elevation_deg + d_elevation, beam_azimuth_angles =
azimuth_offset_deg + d_azimuth (degrees, 6 decimals). Without the original, the beam_intrinsics
object of the Ouster HTTP API is written (angles, lidar_origin_to_beam_origin_mm,
beam_to_lidar_transform). The Ouster format has no per-beam range or height offset: a
calibration's d_range_m and h_z_m are left out, and the notes say by how much.
"""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np

from graphcal.common.atomic import atomic_path
from graphcal.common.errors import ConfigError
from graphcal.importers.ouster_metadata import SECTIONS
from graphcal.recording.sensor import SensorModel

DECIMALS = 6  # degrees: a micro-degree, far below any calibration's precision
_DROPPED_M = 1e-4  # d_range / h_z smaller than this are not worth a note


def ouster_metadata(sensor: SensorModel, offsets: np.ndarray, original: dict | None = None) -> tuple[dict, list[str]]:
    """(metadata JSON object, notes). sensor: the recording's nominal model (an Ouster one, lidar
    frame); offsets: (n_fibres, 4) calibration offsets in (m, rad, rad, m); original: the unit's
    metadata JSON as parsed (kept whole but for the two angle lists)."""
    offsets = np.asarray(offsets, dtype=np.float64)
    if offsets.shape != (sensor.n_fibres, 4):
        raise ConfigError(f"offsets of shape {offsets.shape}: expected ({sensor.n_fibres}, 4), one row per fibre")
    altitude = np.round(sensor.elevation_deg + np.degrees(offsets[:, 2]), DECIMALS)
    azimuth = np.round(sensor.azimuth_offset_deg + np.degrees(offsets[:, 1]), DECIMALS)
    beams = {"beam_altitude_angles": _numbers(altitude), "beam_azimuth_angles": _numbers(azimuth)}
    if original is None:
        origin_mm = sensor.beam_origin_m * 1000.0
        transform = np.eye(4)
        transform[0, 3], transform[2, 3] = origin_mm, sensor.height_offset_m[0] * 1000.0
        metadata = {"beam_intrinsics": beams | {"lidar_origin_to_beam_origin_mm": origin_mm,
                                                "beam_to_lidar_transform": _numbers(transform.ravel())}}
    else:
        metadata = copy.deepcopy(original)
        for name, values in beams.items():
            _set(metadata, name, values, sensor.n_fibres)
    notes = []
    for column, name, what in ((0, "d_range_m", "range offsets"), (3, "h_z_m", "height offsets")):
        largest = float(np.abs(offsets[:, column]).max())
        if largest > _DROPPED_M:
            notes.append(f"the Ouster metadata has no per-beam {what}: {name} left out (largest "
                         f"{largest * 1000:.1f} mm)")
    return metadata, notes


def write_ouster_json(path: str | Path, sensor: SensorModel, offsets: np.ndarray,
                      original: dict | None = None) -> list[str]:
    """Write ouster_metadata(...) to path atomically (4-space indented JSON); returns the notes."""
    metadata, notes = ouster_metadata(sensor, offsets, original)
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(metadata, indent=4) + "\n", encoding="utf-8")
    return notes


def _set(metadata: dict, name: str, values: list[float], n_fibres: int) -> None:
    """Replace a beam field where the original keeps it (its section, or the top)."""
    section = metadata.get(SECTIONS[name])
    holder = section if isinstance(section, dict) and name in section else metadata
    if not isinstance(holder.get(name), list) or len(holder[name]) != n_fibres:
        raise ConfigError(f"the original metadata's {name} has {len(holder.get(name) or [])} beams, the "
                          f"calibration {n_fibres}: expected the metadata of the unit that was calibrated")
    holder[name] = values


def _numbers(values: np.ndarray) -> list[float]:
    """Floats as JSON numbers, integral ones as integers (as the sensor writes 0, not 0.0)."""
    return [int(v) if float(v).is_integer() else float(v) for v in values]
