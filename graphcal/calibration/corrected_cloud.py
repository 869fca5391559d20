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
from graphcal.calibration.result import Calibration, drive_of
from graphcal.clouds.formats import cloud_writer
from graphcal.common.errors import ConfigError, RecordingError
from graphcal.recording.points import PointTable
from graphcal.common.progress import progress
from graphcal.recording.directory import Recording

RESIDUALS = "residuals.parquet"
BATCH_ROWS = 1 << 18  # returns georeferenced and written at a time


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


def corrections_cover(calibration: Calibration, recording: Recording, path: Path) -> None:
    """ConfigError when the calibration's trajectory corrections (made on one drive) are not this recording's: it
    was made on another (calibration.drive), or at times the recording's trajectory never reaches."""
    times = calibration.control_times_s
    if len(times) == 0:
        return
    if calibration.drive is not None and calibration.drive != drive_of(recording):
        made_on = calibration.drive
        raise ConfigError(f"{path}: the calibration's trajectory corrections were made on {made_on['name']} "
                          f"({made_on['returns']:,} returns), not on {recording.path or recording.name} "
                          f"({len(recording.points):,} returns): they apply only to the drive they were made on "
                          "(a calibration without them, mode joint or intrinsic, applies to any drive of the unit)")
    first, last = recording.world.poses.span
    if times[-1] < first or times[0] > last:
        raise ConfigError(f"{path}: the calibration's trajectory corrections cover {times[0]:.3f}-{times[-1]:.3f} s, "
                          f"the recording {recording.path or recording.name} spans {first:.3f}-{last:.3f} s: "
                          "trajectory corrections apply only to the drive they were made on")


def write_corrected_cloud(path: Path, calibration: Calibration, recording: Recording,
                          residuals: tuple[np.ndarray, np.ndarray] | None = None, quiet: bool = False,
                          calibration_path: Path | None = None) -> Path:
    """Every return of `recording` placed with `calibration`, written by the file's suffix
    (.las, .laz, .ply) BATCH_ROWS returns at a time (memory stays flat: about 1 kB per return of
    a batch); residuals: (rows, residual [m]) of the calibration's own recording; calibration_path: the file the
    calibration was read from, which a refusal of its trajectory corrections names (None: path)."""
    corrections_cover(calibration, recording, calibration_path or path)
    n_points = len(recording.points)
    residual = np.full(n_points, np.nan, dtype=np.float32)
    if residuals is not None:
        residual[residuals[0]] = residuals[1]
    # LAS integer coordinates from whole metres near the cloud: the trajectory's lower corner
    writer = cloud_writer(path, n_points, np.floor(recording.world.poses.position_m.min(axis=0)),
                          crs=recording.world.crs)
    batches = recording.points.iter_batches(["time", "fibre", "range", "azimuth", "intensity"], BATCH_ROWS)
    start = 0
    with writer as write:
        for batch in progress(batches, f"writing {path}", total=-(-n_points // BATCH_ROWS), quiet=quiet):
            part = recording.with_points(PointTable.from_arrays(**batch))
            rows = slice(start, start + len(batch["time"]))
            write(apply_calibration(calibration, part), time=batch["time"], intensity=batch["intensity"],
                  fibre=batch["fibre"].astype(np.uint8), residual_m=residual[rows])
            start = rows.stop
    return Path(path)
