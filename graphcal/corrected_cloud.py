"""The recording's cloud georeferenced with a calibration, written as LAS/LAZ or PLY (graphcal apply).

Coordinates are the recording's projected world CRS [m] (in the LAS header as WKT, in a PLY
comment); per point: GPS time [s] (LAS gps_time, PLY "time"), intensity, fibre and residual_m.
residual_m [m] is the root mean square of the point-to-plane residuals of the calibration's final
fit in which the return is p (residuals.parquet of its run folder; a return may be p of pairs
with several neighbour fibres); NaN for every other return, and for all of them when the
calibration comes from another recording.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from graphcal.calibration.evaluate import apply_calibration
from graphcal.calibration.result import Calibration
from graphcal.cloud_io import write_cloud
from graphcal.errors import RecordingError
from graphcal.recording import Recording

RESIDUALS = "residuals.parquet"


def read_residuals(path: Path, n_points: int) -> tuple[np.ndarray, np.ndarray]:
    """(rows, RMS residual [m] per row) of a run folder's residuals.parquet (one row per pair),
    rows checked against n_points."""
    table = pq.read_table(path, columns=["row", "residual_m"])
    rows, residual = table.column("row").to_numpy(), table.column("residual_m").to_numpy().astype(np.float64)
    if len(rows) and (rows.min() < 0 or rows.max() >= n_points):
        raise RecordingError(path, f"row {int(rows.max())}", field="row",
                             expected=f"rows of the recording's {n_points:,} returns")
    unique, index = np.unique(rows, return_inverse=True)
    mean_square = np.bincount(index, residual ** 2) / np.bincount(index)
    return unique, np.sqrt(mean_square)


def write_corrected_cloud(path: Path, calibration: Calibration, recording: Recording,
                          residuals: tuple[np.ndarray, np.ndarray] | None = None) -> Path:
    """Every return of `recording` placed with `calibration`, written by the file's suffix
    (.las, .laz, .ply); residuals: (rows, residual [m]) of the calibration's own recording."""
    xyz = apply_calibration(calibration, recording)
    columns = recording.points.read(["time", "fibre", "intensity"])
    residual = np.full(len(xyz), np.nan, dtype=np.float32)
    if residuals is not None:
        residual[residuals[0]] = residuals[1]
    return write_cloud(path, xyz, crs=recording.world.crs, time=columns["time"],
                       intensity=columns["intensity"], fibre=columns["fibre"].astype(np.uint8), residual_m=residual)
