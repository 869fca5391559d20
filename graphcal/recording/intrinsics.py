"""Per-fibre intrinsic offsets of eq. 4.2: (d_rho m, d_theta rad, d_phi rad, Hz m) per fibre."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from graphcal.common.errors import RecordingError
from graphcal.common.tables import read_csv_columns, write_csv_columns

CSV_COLUMNS = ("fibre", "d_range_m", "d_azimuth_deg", "d_elevation_deg", "h_z_m")
# scale from internal SI units (m, rad, rad, m) to the file units (m, deg, deg, m)
_TO_FILE_UNITS = np.array([1.0, np.degrees(1.0), np.degrees(1.0), 1.0])
# how the intrinsics are shown (tables, viewer, evaluation): the file's (m, deg, deg, m) as (cm, deg, deg, cm)
DISPLAY_NAMES = ("d_range_cm", "d_azimuth_deg", "d_elevation_deg", "h_z_cm")
DISPLAY_FROM_FILE_UNITS = np.array([100.0, 1.0, 1.0, 100.0])


def offsets_to_file_units(offsets_si: np.ndarray) -> np.ndarray:
    """(n, 4) offsets in (m, rad, rad, m) -> (m, deg, deg, m)."""
    return np.asarray(offsets_si, dtype=np.float64) * _TO_FILE_UNITS


def offsets_from_file_units(offsets: np.ndarray) -> np.ndarray:
    """(n, 4) offsets in (m, deg, deg, m) -> (m, rad, rad, m)."""
    return np.asarray(offsets, dtype=np.float64) / _TO_FILE_UNITS


def save_offsets_csv(path: Path, offsets_si: np.ndarray) -> None:
    table = np.column_stack([np.arange(len(offsets_si)), offsets_to_file_units(offsets_si)])
    write_csv_columns(path, CSV_COLUMNS, table, formats=["%d"] + ["%.9g"] * 4)


def load_offsets_csv(path: Path, n_fibres: int) -> np.ndarray:
    """truth/intrinsics.csv -> (n_fibres, 4) offsets in (m, rad, rad, m)."""
    _, values = read_csv_columns(path, (CSV_COLUMNS,))
    if len(values) != n_fibres or not np.array_equal(values[:, 0], np.arange(n_fibres)):
        raise RecordingError(path, f"{len(values)} rows", field="fibre",
                             expected=f"one row per fibre, ids 0..{n_fibres - 1} in order")
    return offsets_from_file_units(values[:, 1:])
