"""A recording directory (RECORDING.md, graphcal-recording/1): load, validate, save."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path

from graphcal.common.atomic import atomic_directory
from graphcal.common.errors import RecordingError
from graphcal.recording.extrinsic import Extrinsic
from graphcal.recording.geodesy import WorldTrajectory, resolve_crs, to_world
from graphcal.recording.odometry import Odometry
from graphcal.recording.points import PointSummary, PointTable
from graphcal.recording.sensor import SensorModel
from graphcal.recording.trajectory import Trajectory
from graphcal.recording.truth import Truth
from graphcal.common.yamlfile import read_yaml, write_yaml

FORMAT = "graphcal-recording/1"


@dataclass
class Recording:
    """One drive: nominal sensor, initial extrinsic, trajectory, raw returns (+ odometry, truth).

    Points stay on disk and are read in batches (`points.iter_batches`). `truth` is None for
    real data; for simulated data it is loaded only when evaluation code asks for it.
    """

    name: str
    crs: str
    sensor: SensorModel
    extrinsic: Extrinsic
    trajectory: Trajectory
    points: PointTable
    odometry: Odometry | None = None
    source: dict | None = None  # where an importer got the data from and what it assumed (recording.yaml)
    path: Path | None = None
    _truth: Truth | None = field(default=None, repr=False)

    @cached_property
    def world(self) -> WorldTrajectory:
        """T_world_body(t) in the projected world frame, with grid scale and convergence; the recorded poses'
        white noise, where they carry some, smoothed out (WorldTrajectory.white_noise says how much)."""
        return to_world(self.trajectory, self.crs, self._source("recording.yaml")).smoothed()

    def with_points(self, points: PointTable) -> Recording:
        """The same drive with other returns (a batch of them): the world trajectory is shared,
        not transformed again."""
        other = replace(self, points=points)
        if "world" in self.__dict__:
            other.__dict__["world"] = self.world
        return other

    @property
    def truth(self) -> Truth | None:
        if self._truth is None and self.path is not None and (self.path / "truth").is_dir():
            self._truth = Truth.load(self.path / "truth", self.sensor.n_fibres)
        return self._truth

    def _source(self, name: str) -> Path:
        return (self.path or Path(self.name)) / name

    # --- load ------------------------------------------------------------------------------
    @classmethod
    def load(cls, path: str | Path, validate: bool = True) -> Recording:
        """Open a recording directory. With validate, every file is checked (points in batches)
        and the trajectory must cover the points' time span; errors name file, field and row."""
        path = Path(path)
        if not path.is_dir():
            raise RecordingError(path, "recording directory not found" if not path.exists() else "not a directory")
        manifest = read_yaml(path / "recording.yaml")
        if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
            found = manifest.get("format") if isinstance(manifest, dict) else manifest
            raise RecordingError(path / "recording.yaml", f"format is {found!r}", field="format", expected=FORMAT)
        crs = str(manifest.get("crs", "auto"))
        sensor = SensorModel.from_dict(read_yaml(path / "sensor.yaml"), path / "sensor.yaml")
        extrinsic = Extrinsic.from_dict(read_yaml(path / "extrinsic.yaml"), path / "extrinsic.yaml")
        trajectory = Trajectory.load_csv(path / "trajectory.csv")
        resolve_crs(crs, trajectory, path / "recording.yaml")
        odometry = None
        if (path / "odometry.csv").exists():
            odometry = Odometry.load_csv(path / "odometry.csv", manifest.get("odometry"), path / "recording.yaml")
        source = manifest.get("source")
        recording = cls(name=str(manifest.get("name", path.name)), crs=crs, sensor=sensor, extrinsic=extrinsic,
                        trajectory=trajectory, points=PointTable.open(path / "points.parquet"),
                        odometry=odometry, source=source if isinstance(source, dict) else None, path=path)
        if validate:
            recording.validate()
        return recording

    def validate(self) -> PointSummary:
        """Check every return (in batches) and that the trajectory covers their time span."""
        summary = self.points.validate(self.sensor.n_fibres, self._source("points.parquet"))
        start, end = self.trajectory.time[0], self.trajectory.time[-1]
        if summary.time_min < start or summary.time_max > end:
            raise RecordingError(self._source("trajectory.csv"),
                                 f"poses span [{start:.6f}, {end:.6f}] s", field="time",
                                 expected=f"poses covering the returns' span [{summary.time_min:.6f}, "
                                          f"{summary.time_max:.6f}] s")
        return summary

    # --- save ------------------------------------------------------------------------------
    def save(self, path: str | Path) -> Path:
        """Write the whole recording atomically (a temporary directory renamed at the end)."""
        path = Path(path)
        truth = self.truth
        with atomic_directory(path) as tmp:
            self.points.save(tmp / "points.parquet")
            if truth is not None:
                truth.save_world_points(tmp / "truth")
            self.save_beside_points(tmp)
        self.path = path
        self.points = PointTable.open(path / "points.parquet")
        return path

    def save_beside_points(self, directory: Path) -> None:
        """Every file of the recording but points.parquet and truth's world points, into `directory`
        (save() writes those too; a streaming simulation writes them as it goes)."""
        manifest = {"format": FORMAT, "name": self.name, "crs": self.crs}
        if self.odometry is not None:
            manifest["odometry"] = self.odometry.params()
        if self.source:
            manifest["source"] = self.source
        write_yaml(directory / "recording.yaml", manifest)
        write_yaml(directory / "sensor.yaml", self.sensor.to_dict())
        write_yaml(directory / "extrinsic.yaml", self.extrinsic.to_dict())
        self.trajectory.save_csv(directory / "trajectory.csv")
        if self.odometry is not None:
            self.odometry.save_csv(directory / "odometry.csv")
        if self.truth is not None:
            self.truth.save_beside_world_points(directory / "truth")
