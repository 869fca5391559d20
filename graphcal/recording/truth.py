"""truth/ of a simulated recording. Only evaluation code may read it (RECORDING.md)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from graphcal.common.atomic import atomic_path
from graphcal.recording.extrinsic import Extrinsic
from graphcal.recording.intrinsics import load_offsets_csv, save_offsets_csv
from graphcal.recording.points import row_group_writer
from graphcal.recording.trajectory import Trajectory
from graphcal.common.yamlfile import read_yaml, write_yaml

WORLD_POINTS = "points.parquet"
_WORLD_SCHEMA = pa.schema([(name, pa.float64()) for name in "xyz"])


@contextmanager
def world_point_writer(path: Path) -> Iterator[Callable[[np.ndarray], None]]:
    """truth/points.parquet written as it goes: each write(xyz (N,3) true world position [m, world frame])
    appends its rows as row groups. Not atomic by itself: write into a temporary path."""
    with row_group_writer(path, _WORLD_SCHEMA) as write:
        yield lambda xyz: write({name: xyz[:, k] for k, name in enumerate("xyz")})


@dataclass
class Truth:
    """True intrinsic offsets (n,4; m, rad, rad, m), extrinsic, trajectory and switched-on effects.

    The true world position [m, world frame] of every return, row-aligned with points.parquet,
    is read on demand by world_points() (it is as large as the recording).
    """

    intrinsics: np.ndarray
    extrinsic: Extrinsic
    trajectory: Trajectory
    effects: dict
    _world_points: np.ndarray | None = field(default=None, repr=False)
    _directory: Path | None = field(default=None, repr=False)

    def world_points(self) -> np.ndarray:
        """(N,3) true world xyz [m] of every return, in the order of points.parquet."""
        if self._world_points is None:
            table = pq.read_table(self._directory / WORLD_POINTS)
            self._world_points = np.column_stack([table.column(n).to_numpy() for n in "xyz"])
        return self._world_points

    def save_world_points(self, directory: Path) -> None:
        """truth/points.parquet, atomically."""
        with atomic_path(directory / WORLD_POINTS) as tmp, world_point_writer(tmp) as write:
            write(self.world_points())

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
