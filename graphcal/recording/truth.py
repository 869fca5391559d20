"""truth/ of a simulated recording. Only evaluation code may read it (RECORDING.md)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa

from graphcal.common.atomic import atomic_path
from graphcal.common.errors import RecordingError
from graphcal.recording.extrinsic import Extrinsic
from graphcal.recording.intrinsics import load_offsets_csv, save_offsets_csv
from graphcal.recording.points import PointTable, row_group_writer
from graphcal.recording.trajectory import Trajectory
from graphcal.common.yamlfile import read_yaml, write_yaml

WORLD_POINTS = "points.parquet"
_WORLD_SCHEMA = pa.schema([(name, pa.float64()) for name in "xyz"])
MOVING = "moving"  # truth/points.parquet's column: the return is on a moving object of the traffic (bool)


@contextmanager
def world_point_writer(path: Path, moving: bool = False) -> Iterator[Callable[..., None]]:
    """truth/points.parquet written as it goes: each write(xyz (N,3) true world position [m, world frame],
    moving (N,) bool, with moving=True) appends its rows as row groups. Not atomic by itself: write into a
    temporary path."""
    schema = _WORLD_SCHEMA.append(pa.field(MOVING, pa.bool_())) if moving else _WORLD_SCHEMA

    def columns(xyz: np.ndarray, on_mover: np.ndarray | None = None) -> dict:
        named = {name: xyz[:, k] for k, name in enumerate("xyz")}
        return named | ({MOVING: on_mover} if moving else {})

    with row_group_writer(path, schema) as write:
        yield lambda xyz, on_mover=None: write(columns(xyz, on_mover))


@dataclass
class Truth:
    """True intrinsic offsets (n,4; m, rad, rad, m), extrinsic, trajectory and switched-on effects.

    The true world position [m, world frame] of every return, row-aligned with points.parquet,
    is read on demand by world_points() (it is as large as the recording); which returns are on a moving
    object of the traffic by moving().
    """

    intrinsics: np.ndarray
    extrinsic: Extrinsic
    trajectory: Trajectory
    effects: dict
    _world_points: np.ndarray | None = field(default=None, repr=False)
    _moving: np.ndarray | None = field(default=None, repr=False)
    _directory: Path | None = field(default=None, repr=False)

    def world_points(self) -> np.ndarray:
        """(N,3) true world xyz [m] of every return, in the order of points.parquet."""
        if self._world_points is None:
            columns = self._table().read(list("xyz"))
            self._world_points = np.column_stack([columns[n] for n in "xyz"])
        return self._world_points

    def world_points_at(self, rows: np.ndarray) -> np.ndarray:
        """(len(rows),3) true world xyz [m] of the given returns (sorted rows of points.parquet), read batch by
        batch when on disk: only those rows are held, whatever the recording's length."""
        if self._world_points is not None or self._directory is None:
            return self.world_points()[rows]
        table = self._table()
        if len(rows) and rows[-1] >= len(table):
            raise RecordingError(table.path, f"{len(table)} rows, none for return {rows[-1]} of points.parquet",
                                 expected="a true world position for every return")
        columns = table.take(list("xyz"), rows)
        return np.column_stack([columns[n] for n in "xyz"])

    def _table(self) -> PointTable:
        """truth/points.parquet (RecordingError naming it when it is missing, not Parquet or lacks x, y, z)."""
        table = PointTable.open(self._directory / WORLD_POINTS)
        missing = [name for name in "xyz" if name not in table.column_names]
        if missing:
            raise RecordingError(table.path, f"no column {', '.join(missing)}", expected="columns x, y, z [m]")
        return table

    def moving(self) -> np.ndarray:
        """(N,) bool: the return is on a moving object of the traffic (all False for a scene without one)."""
        if self._moving is None:
            table = self._table() if self._directory is not None else None
            if table is not None and MOVING in table.column_names:
                self._moving = table.read([MOVING])[MOVING]
            else:
                self._moving = np.zeros(len(self.world_points()), dtype=bool)
        return self._moving

    def save_world_points(self, directory: Path) -> None:
        """truth/points.parquet, atomically (with the moving column when some return is on traffic)."""
        moving = self._moving is not None and bool(self.moving().any())
        with atomic_path(directory / WORLD_POINTS) as tmp, world_point_writer(tmp, moving) as write:
            write(self.world_points(), self.moving() if moving else None)

    def save_beside_world_points(self, directory: Path) -> None:
        """Every file of truth/ but the world points (which a streaming simulation writes as it goes)."""
        directory.mkdir(parents=True, exist_ok=True)
        save_offsets_csv(directory / "intrinsics.csv", self.intrinsics)
        write_yaml(directory / "extrinsic.yaml", self.extrinsic.to_dict())
        self.trajectory.save_csv(directory / "trajectory.csv")
        write_yaml(directory / "effects.yaml", self.effects)

    @classmethod
    def load(cls, directory: Path, n_fibres: int) -> Truth:
        return cls(intrinsics=load_offsets_csv(directory / "intrinsics.csv", n_fibres),
                   extrinsic=Extrinsic.from_dict(read_yaml(directory / "extrinsic.yaml"), directory / "extrinsic.yaml"),
                   trajectory=Trajectory.load_csv(directory / "trajectory.csv"),
                   effects=read_yaml(directory / "effects.yaml") or {}, _directory=directory)
