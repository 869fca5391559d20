"""truth/ of a simulated recording. Only evaluation code may read it (RECORDING.md)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from graphcal.common.atomic import atomic_path
from graphcal.recording.extrinsic import Extrinsic
from graphcal.recording.intrinsics import load_offsets_csv, save_offsets_csv
from graphcal.recording.trajectory import Trajectory
from graphcal.common.yamlfile import read_yaml, write_yaml

WORLD_POINTS = "points.parquet"


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

    def save(self, directory: Path) -> None:
        directory.mkdir(parents=True, exist_ok=True)
        save_offsets_csv(directory / "intrinsics.csv", self.intrinsics)
        write_yaml(directory / "extrinsic.yaml", self.extrinsic.to_dict())
        self.trajectory.save_csv(directory / "trajectory.csv")
        write_yaml(directory / "effects.yaml", self.effects)
        xyz = self.world_points()
        with atomic_path(directory / WORLD_POINTS) as tmp:
            pq.write_table(pa.table({n: xyz[:, k] for k, n in enumerate("xyz")}), tmp,
                           compression="zstd", row_group_size=1 << 20)

    @classmethod
    def load(cls, directory: Path, n_fibres: int) -> Truth:
        return cls(intrinsics=load_offsets_csv(directory / "intrinsics.csv", n_fibres),
                   extrinsic=Extrinsic.from_dict(read_yaml(directory / "extrinsic.yaml"), directory / "extrinsic.yaml"),
                   trajectory=Trajectory.load_csv(directory / "trajectory.csv"),
                   effects=read_yaml(directory / "effects.yaml") or {}, _directory=directory)
