"""The recording directory of RECORDING.md (graphcal-recording/1), written with pyarrow, PyYAML
and numpy only."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import yaml

FORMAT = "graphcal-recording/1"
POINT_SCHEMA = pa.schema([("time", pa.float64()), ("fibre", pa.int16()), ("range", pa.float32()),
                          ("azimuth", pa.float32()), ("intensity", pa.float32()), ("scan", pa.int32())])
TRUTH_POINT_SCHEMA = pa.schema([("x", pa.float64()), ("y", pa.float64()), ("z", pa.float64())])
TRAJECTORY_HEADER = ("time", "x", "y", "z", "roll", "pitch", "yaw")
INTRINSICS_HEADER = ("fibre", "d_range_m", "d_azimuth_deg", "d_elevation_deg", "h_z_m")


def write_yaml(path: Path, data) -> None:
    path.write_text(yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=100))


def write_csv(path: Path, header, values: np.ndarray, formats) -> None:
    np.savetxt(path, values, delimiter=",", header=",".join(header), comments="", fmt=formats)


def write_trajectory(path: Path, time, position, rpy_deg) -> None:
    """Projected trajectory.csv: time [s], x, y, z [m], roll, pitch, yaw [deg], yaw in [-180, 180)."""
    rpy = np.array(rpy_deg, dtype=np.float64)
    rpy[:, 2] = np.mod(rpy[:, 2] + 180.0, 360.0) - 180.0
    values = np.column_stack([time, position, rpy])
    write_csv(path, TRAJECTORY_HEADER, values, ["%.9f"] + ["%.6f"] * 3 + ["%.9f"] * 3)


def write_intrinsics(path: Path, offsets_si: np.ndarray) -> None:
    """truth/intrinsics.csv from (n, 4) offsets in (m, rad, rad, m)."""
    o = np.asarray(offsets_si, dtype=np.float64)
    values = np.column_stack([np.arange(len(o)), o[:, 0], np.degrees(o[:, 1]), np.degrees(o[:, 2]), o[:, 3]])
    write_csv(path, INTRINSICS_HEADER, values, ["%d"] + ["%.9g"] * 4)


class RowGroupWriter:
    """Parquet written in row groups of at least `group_rows` rows, so memory stays bounded."""

    def __init__(self, path: Path, schema: pa.Schema, group_rows: int = 1 << 20):
        self.schema, self.group_rows = schema, group_rows
        self.writer = pq.ParquetWriter(path, schema, compression="zstd")
        self.pending: list[dict[str, np.ndarray]] = []
        self.pending_rows = 0
        self.rows = 0

    def append(self, columns: dict[str, np.ndarray]) -> None:
        n = len(next(iter(columns.values())))
        if n == 0:
            return
        self.pending.append(columns)
        self.pending_rows += n
        if self.pending_rows >= self.group_rows:
            self.flush()

    def flush(self) -> None:
        if not self.pending:
            return
        arrays = [pa.array(np.concatenate([c[f.name] for c in self.pending]), type=f.type) for f in self.schema]
        self.writer.write_table(pa.Table.from_arrays(arrays, schema=self.schema), row_group_size=self.pending_rows)
        self.rows += self.pending_rows
        self.pending, self.pending_rows = [], 0

    def close(self) -> None:
        self.flush()
        self.writer.close()


def prepare_output(out: Path) -> Path:
    """A fresh temporary sibling directory to write into (renamed onto `out` by `commit_output`).

    `out` may not exist, be empty, or be an earlier recording (it is then replaced)."""
    out = Path(out)
    if out.exists():
        if not out.is_dir():
            raise FileExistsError(f"{out} exists and is not a directory")
        if any(out.iterdir()) and not (out / "recording.yaml").exists():
            raise FileExistsError(f"{out} is a non-empty directory that is not a recording; not overwriting it")
    tmp = out.parent / f".{out.name}.foreign-sim-tmp"
    if tmp.exists():
        shutil.rmtree(tmp)
    (tmp / "truth").mkdir(parents=True)
    return tmp


def commit_output(tmp: Path, out: Path) -> Path:
    out = Path(out)
    if out.exists():
        shutil.rmtree(out)
    tmp.rename(out)
    return out
