"""An import's recording folder written as the raw returns are recovered, in memory bounded by a chunk of them.

points.parquet gets each chunk as it comes (RECORDING.md's columns, sorted by time within a bounded
buffer: graphcal.recording.points.time_sorted_writer); the notes get what holds for all the returns:
how many, their model misfit (beam_fit.MisfitSpread) and how their intensities were brought into
0-255. That scale needs the largest intensity of the whole input, so the intensities are written as
stored (negatives as 0) and, when they do not fit 0-255 as they are, scaled in a second pass over
points.parquet, one row group at a time. The importers write into a temporary folder that appears
whole or not at all (atomic_directory), after save_imported has checked every return (graphcal info
must accept what an import writes).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from graphcal.common.atomic import atomic_directory, atomic_path
from graphcal.common.errors import ConfigError, RecordingError
from graphcal.importers.beam_fit import MisfitSpread
from graphcal.recording.directory import Recording
from graphcal.recording.points import SCHEMA, PointTable, point_schema, row_group_writer, time_sorted_writer

POINTS = "points.parquet"


@dataclass
class IntensityRange:
    """What the intensities of all the returns decide the 0-255 scale by: the largest (negatives as 0) and whether
    any is not a whole number."""

    top: float = 0.0
    fractional: bool = False

    def add(self, intensity: np.ndarray) -> None:
        if len(intensity):
            self.top = max(self.top, float(np.max(intensity)))
            self.fractional = self.fractional or bool(np.any(intensity % 1.0 != 0.0))

    @property
    def factor(self) -> float:
        """The scale into 0-255: x255 when within 0-1 (a reflectance), 1 when within 0-255, else 255 / the top."""
        if self.top <= 1.0 and self.fractional:
            return 255.0
        return 1.0 if self.top <= 255.0 else 255.0 / self.top

    @property
    def note(self) -> str:
        if self.top <= 1.0 and self.fractional:
            return "intensity within 0-1 (a reflectance): multiplied by 255"
        if self.top <= 255.0:
            return "intensity as stored (0-255)"
        return f"intensity scaled by 255 / {self.top:g} (the largest value) into 0-255"


class ReturnWriter:
    """The returns of an import on their way into points.parquet, and what the notes say of them all."""

    def __init__(self, write: Callable[[dict[str, np.ndarray]], None]):
        self._write = write
        self.intensity, self.misfit = IntensityRange(), MisfitSpread()
        self.n_returns = 0

    def add(self, columns: dict[str, np.ndarray], misfit_m: np.ndarray | None = None) -> None:
        """A chunk of returns: RECORDING.md's columns (time in the recording's time base [s], intensity as stored)
        and their model misfit [m] (None for raw returns read as the sensor sent them)."""
        intensity = np.maximum(np.asarray(columns["intensity"], dtype=np.float64), 0.0)
        self.intensity.add(intensity)
        if misfit_m is not None:
            self.misfit.add(misfit_m)
        self.n_returns += len(intensity)
        self._write({**columns, "intensity": intensity})


@contextmanager
def return_writer(folder: Path, source: Path, expected_order: str, columns: list[str]
                  ) -> Iterator[ReturnWriter]:
    """folder/points.parquet (the given columns of RECORDING.md) written chunk by chunk through the ReturnWriter
    yielded, its intensities scaled into 0-255 when the writer closes. source: the input named in errors;
    expected_order: how far out of time order the input may be (time_sorted_writer)."""
    path = folder / POINTS
    with time_sorted_writer(path, point_schema(columns), source, expected_order) as write:
        returns = ReturnWriter(write)
        yield returns
    if returns.intensity.factor != 1.0:
        _scale_intensity(path, returns.intensity.factor)


def _scale_intensity(path: Path, factor: float) -> None:
    """points.parquet rewritten (atomically, row group by row group) with its intensities times `factor`, computed
    in float64 as a whole-file scaling would be."""
    table = PointTable.open(path)
    with atomic_path(path) as tmp, row_group_writer(tmp, point_schema(table.column_names)) as write:
        for batch in table.iter_batches(table.column_names):
            write({**batch, "intensity": batch["intensity"].astype(np.float64) * factor})


def check_imported(recording: Recording, source: Path) -> None:
    """Every imported return checked as graphcal info would (an importer's arithmetic on a damaged input must
    not write a recording that info refuses); ConfigError naming the input when one fails."""
    try:
        recording.validate()
    except RecordingError as error:
        raise ConfigError(f"{source}: the returns imported from it do not form a valid recording ({error})") from None


def save_imported(recording: Recording, folder: Path, source: Path) -> None:
    """The recording whose points are folder/points.parquet: checked (check_imported), then its other files
    written beside them."""
    check_imported(recording, source)
    recording.save_beside_points(folder)


def write_import(out: Path, source: Path, expected_order: str,
                 chunks: Iterable[tuple[dict[str, np.ndarray], np.ndarray | None]],
                 finish: Callable[[ReturnWriter, PointTable], Recording]) -> Recording:
    """The recording folder `out` (written whole or not at all; an existing one is replaced) of the returns given
    chunk after chunk: (RECORDING.md's columns, their model misfit [m] or None) as ReturnWriter.add takes them,
    written through return_writer; `finish` makes the recording of them (its notes from the writer, its points the
    table written) once they are all out, then save_imported checks and writes it. source, expected_order: as
    return_writer."""
    with atomic_directory(out) as folder:
        with return_writer(folder, source, expected_order, list(SCHEMA)) as returns:
            for columns, misfit_m in chunks:
                returns.add(columns, misfit_m)
        save_imported(finish(returns, PointTable.open(folder / POINTS)), folder, source)
    return Recording.load(out, validate=False)
