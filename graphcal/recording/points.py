"""points.parquet: raw returns, written in row groups as they come (sorted by time in bounded memory), read
lazily in row batches, validated batch by batch."""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from graphcal.common.atomic import atomic_path
from graphcal.common.errors import RecordingError

# column -> (arrow type written, kinds accepted on read, required)
SCHEMA = {
    "time": (pa.float64(), ("float64",), True),
    "fibre": (pa.int16(), ("int",), True),
    "range": (pa.float32(), ("float",), True),
    "azimuth": (pa.float32(), ("float",), True),
    "intensity": (pa.float32(), ("float", "int"), True),
    "scan": (pa.int32(), ("int",), False),
}
BATCH_ROWS = 1 << 20
# no lidar measures farther (an airborne one flies a few km up): beyond it a range is damaged or not in metres
MAX_RANGE_M = 100_000.0


def point_schema(column_names: Sequence[str]) -> pa.Schema:
    """The contract's columns among column_names, in the contract's order and types."""
    return pa.schema([(name, SCHEMA[name][0]) for name in SCHEMA if name in column_names])


@contextmanager
def row_group_writer(path: Path, schema: pa.Schema) -> Iterator[Callable[[dict[str, np.ndarray]], None]]:
    """A Parquet file (zstd) written as it goes: each write(columns) appends its rows, cast to the schema's
    types, as row groups of at most BATCH_ROWS rows (an empty write adds nothing). Not atomic by itself:
    write into a temporary path (graphcal.common.atomic)."""
    with pq.ParquetWriter(path, schema, compression="zstd") as writer:
        def write(columns: dict[str, np.ndarray]) -> None:
            if len(columns[schema.names[0]]):
                typed = {field.name: np.asarray(columns[field.name], dtype=field.type.to_pandas_dtype())
                         for field in schema}
                writer.write_table(pa.table(typed, schema=schema), row_group_size=BATCH_ROWS)
        yield write


@contextmanager
def time_sorted_writer(path: Path, schema: pa.Schema, source: Path | str, expected: str
                       ) -> Iterator[Callable[[dict[str, np.ndarray]], None]]:
    """A Parquet file (zstd) of rows sorted by time, written as they come in bounded memory: each write(columns)
    is merged with the rows held back so far and all but the latest len(columns) rows go out, in row groups of
    BATCH_ROWS rows whatever the writes' sizes. The file holds the stable sort of all the rows by time, the same
    for any split of them into writes, as long as no row is earlier than one already out; when one is (the input
    is out of order by more than one write), RecordingError naming `source`, the time field and `expected`.
    Not atomic by itself: write into a temporary path (graphcal.common.atomic)."""
    with row_group_writer(path, schema) as write:
        sorter = _TimeSorter(write, source, expected)
        yield sorter.add
        sorter.close()


class _TimeSorter:
    """time_sorted_writer's state: the rows held back (sorted) and the rows out but not yet written."""

    def __init__(self, write: Callable[[dict[str, np.ndarray]], None], source: Path | str, expected: str):
        self._write, self._source, self._expected = write, source, expected
        self._held: dict[str, np.ndarray] = {}
        self._out: list[dict[str, np.ndarray]] = []
        self._last_out_s = -np.inf

    def add(self, columns: dict[str, np.ndarray]) -> None:
        time = columns["time"]
        if not len(time):
            return
        if time.min() < self._last_out_s:
            raise RecordingError(self._source, f"time {float(time.min())!r} is before {self._last_out_s!r}, the time "
                                               "of rows already written", field="time", expected=self._expected)
        merged = concatenated_columns([self._held, columns]) if self._held else columns
        order = np.argsort(merged["time"], kind="stable")
        cut = len(order) - len(time)
        self._release({name: values[order[:cut]] for name, values in merged.items()})
        self._held = {name: values[order[cut:]] for name, values in merged.items()}

    def close(self) -> None:
        """Write the rows held back and every row out."""
        self._release(self._held)
        self._held = {}
        if self._out:
            self._write(concatenated_columns(self._out))
            self._out = []

    def _release(self, rows: dict[str, np.ndarray]) -> None:
        """Rows sorted by time, after every row out so far: out, and written in groups of BATCH_ROWS."""
        if not rows or not len(rows["time"]):
            return
        self._last_out_s = float(rows["time"][-1])
        self._out.append(rows)
        waiting = sum(len(part["time"]) for part in self._out)
        if waiting >= BATCH_ROWS:
            out = concatenated_columns(self._out)
            full = waiting - waiting % BATCH_ROWS
            self._write({name: values[:full] for name, values in out.items()})
            self._out = [{name: values[full:] for name, values in out.items()}]


def concatenated_columns(parts: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """Column dicts with the same keys, their rows one after the other."""
    return {name: np.concatenate([part[name] for part in parts]) for name in parts[0]}


def _kind_ok(arrow_type: pa.DataType, kinds: Sequence[str]) -> bool:
    return any({"float64": pa.types.is_float64, "float": pa.types.is_floating,
                "int": pa.types.is_integer}[k](arrow_type) for k in kinds)


def _type_name(arrow_type: pa.DataType) -> str:
    """The contract's spelling of a type (float64, int16, ...), Arrow's for non-numeric ones."""
    if pa.types.is_floating(arrow_type) or pa.types.is_integer(arrow_type):
        return np.dtype(arrow_type.to_pandas_dtype()).name
    return str(arrow_type)


def _expected_type(written: pa.DataType, kinds: Sequence[str]) -> str:
    accepted = {"float64": None, "float": "floating-point", "int": "integer"}
    extra = [accepted[k] for k in kinds if accepted[k]]
    return _type_name(written) + (f" (any {' or '.join(extra)} type is read)" if extra else "")


@dataclass(frozen=True)
class PointSummary:
    """What validation learnt in one pass: row count, time span [s], returns per fibre."""

    n_points: int
    time_min: float
    time_max: float
    count_per_fibre: np.ndarray


class PointTable:
    """Raw returns, either in memory (dict of arrays) or in a Parquet file read on demand."""

    def __init__(self, arrays: dict[str, np.ndarray] | None = None, path: Path | None = None):
        self._arrays, self.path = arrays, path
        # pre_buffer off: with it, Arrow keeps every column chunk read so far (the whole file after a pass)
        self._file = pq.ParquetFile(path, pre_buffer=False) if path is not None else None

    @classmethod
    def from_arrays(cls, **arrays) -> PointTable:
        typed = {name: np.ascontiguousarray(values, dtype=SCHEMA[name][0].to_pandas_dtype())
                 for name, values in arrays.items() if values is not None}
        return cls(arrays=typed)

    @classmethod
    def open(cls, path: Path) -> PointTable:
        path = Path(path)
        if not path.is_file():
            raise RecordingError(path, "file not found")
        try:
            return cls(path=path)
        except (pa.ArrowInvalid, OSError) as error:
            raise RecordingError(path, f"not a Parquet file: {error}") from None

    @property
    def column_names(self) -> list[str]:
        return list(self._arrays) if self._file is None else self._file.schema_arrow.names

    def __len__(self) -> int:
        return len(self._arrays["time"]) if self._file is None else self._file.metadata.num_rows

    def read(self, columns: Sequence[str] | None = None) -> dict[str, np.ndarray]:
        """Whole columns as NumPy arrays (all of them if columns is None)."""
        columns = list(columns or self.column_names)
        if self._file is None:
            return {name: self._arrays[name] for name in columns}
        with self._readable():
            table = self._file.read(columns=columns)
        return {name: table.column(name).to_numpy() for name in columns}

    def take(self, columns: Sequence[str], rows: np.ndarray) -> dict[str, np.ndarray]:
        """The given columns at the given rows (sorted indices), read batch by batch: only those rows are held."""
        rows = np.asarray(rows, dtype=np.int64)
        if np.any(np.diff(rows) < 0):
            raise ValueError("PointTable.take needs sorted rows")
        parts, start = [], 0
        for batch in self.iter_batches(columns):
            n = len(batch[columns[0]])
            taken = rows[np.searchsorted(rows, start):np.searchsorted(rows, start + n)]
            parts.append({name: values[taken - start] for name, values in batch.items()})
            start += n
        return {name: np.concatenate([part[name] for part in parts]) for name in columns}

    def time_span_s(self) -> tuple[float, float]:
        """(first, last) time [s] of the returns (points.parquet is in time order): from the first and the last
        row group only. Needs at least one return."""
        if self._file is None:
            return float(self._arrays["time"][0]), float(self._arrays["time"][-1])
        filled = [k for k in range(self._file.num_row_groups) if self._file.metadata.row_group(k).num_rows]
        with self._readable():
            first = self._file.read_row_group(filled[0], columns=["time"]).column("time")
            last = self._file.read_row_group(filled[-1], columns=["time"]).column("time")
        return float(first[0].as_py()), float(last[-1].as_py())

    def iter_batches(self, columns: Sequence[str], batch_rows: int | None = None) -> Iterator[dict[str, np.ndarray]]:
        """Row batches of the given columns, so that no more than batch_rows rows are in memory
        (BATCH_ROWS, read at call time, when not given)."""
        batch_rows = BATCH_ROWS if batch_rows is None else batch_rows
        if self._file is None:
            for start in range(0, len(self), batch_rows):
                yield {name: self._arrays[name][start:start + batch_rows] for name in columns}
            return
        with self._readable():
            for batch in self._file.iter_batches(batch_size=batch_rows, columns=list(columns)):
                yield {name: batch.column(name).to_numpy(zero_copy_only=False) for name in columns}

    @contextmanager
    def _readable(self):
        """Reading the file: a damaged one (a flipped bit, a cut tail) raises RecordingError naming it."""
        try:
            yield
        except (pa.ArrowInvalid, OSError) as error:
            raise RecordingError(self.path, f"damaged Parquet data: {error}") from None

    def save(self, path: Path) -> None:
        """Write atomically with the contract's column types, in row groups of BATCH_ROWS."""
        schema = point_schema(self.column_names)
        with atomic_path(path) as tmp, row_group_writer(tmp, schema) as write:
            for batch in self.iter_batches(schema.names):
                write(batch)

    def validate(self, n_fibres: int, source: Path | str = "points.parquet") -> PointSummary:
        """Check types, values and time order batch by batch; return what was learnt."""
        self._check_schema(source)
        names = [n for n in SCHEMA if n in self.column_names]
        counts = np.zeros(n_fibres, dtype=np.int64)
        previous_time, start = -np.inf, 0
        time_min, time_max = np.inf, -np.inf
        for batch in self.iter_batches(names):
            _check_batch(batch, start, previous_time, n_fibres, source)
            time = batch["time"]
            if len(time):
                previous_time = time[-1]
                time_min, time_max = min(time_min, time[0]), time[-1]
            counts += np.bincount(batch["fibre"].astype(np.int64), minlength=n_fibres)
            start += len(time)
        if start == 0:
            raise RecordingError(source, "no returns", expected="at least one row")
        return PointSummary(start, float(time_min), float(time_max), counts)

    def _check_schema(self, source) -> None:
        types = (dict(zip(self._file.schema_arrow.names, self._file.schema_arrow.types)) if self._file is not None
                 else {n: pa.from_numpy_dtype(a.dtype) for n, a in self._arrays.items()})
        for name, (written, kinds, required) in SCHEMA.items():
            if name not in types:
                if required:
                    raise RecordingError(source, "missing column", field=name,
                                         expected=f"a column of type {_expected_type(written, kinds)}")
                continue
            if not _kind_ok(types[name], kinds):
                raise RecordingError(source, f"column type is {_type_name(types[name])}", field=name,
                                     expected=_expected_type(written, kinds))


def _check_batch(batch, start, previous_time, n_fibres, source) -> None:
    def fail(name, mask, problem, expected):
        index = int(np.flatnonzero(mask)[0])
        raise RecordingError(source, f"{problem} {batch[name][index].item()!r} at row index {start + index}",
                             field=name, expected=expected)

    for name in batch:  # every column: Parquet nulls read as NaN, in integer columns too
        finite = np.isfinite(batch[name])
        if not finite.all():
            fail(name, ~finite, "value", "finite numbers")
    fibre = batch["fibre"]
    if len(fibre) and (fibre.min() < 0 or fibre.max() >= n_fibres):
        fail("fibre", (fibre < 0) | (fibre >= n_fibres), "fibre id", f"an id of sensor.yaml, 0..{n_fibres - 1}")
    if (batch["range"] < 0).any():
        fail("range", batch["range"] < 0, "negative range", "ranges >= 0 m")
    if (batch["range"] > MAX_RANGE_M).any():
        fail("range", batch["range"] > MAX_RANGE_M, "range", f"ranges within {MAX_RANGE_M:,.0f} m (metres given?)")
    intensity = batch["intensity"]
    if len(intensity) and (intensity.min() < 0 or intensity.max() > 255):
        fail("intensity", (intensity < 0) | (intensity > 255), "intensity", "reflectivity within 0-255")
    azimuth = batch["azimuth"]
    if (np.abs(azimuth) > 2 * np.pi + 1e-4).any():
        fail("azimuth", np.abs(azimuth) > 2 * np.pi + 1e-4, "azimuth", "radians within +-2 pi (degrees given?)")
    time = batch["time"]
    if len(time) and time[0] < previous_time:
        raise RecordingError(source, f"time {float(time[0])!r} at row index {start} is before "
                                     f"{float(previous_time)!r}",
                             field="time", expected="rows sorted by time")
    decreasing = np.diff(time) < 0
    if decreasing.any():
        index = int(np.flatnonzero(decreasing)[0]) + 1
        raise RecordingError(source, f"time {float(time[index])!r} at row index {start + index} is before "
                                     f"{float(time[index - 1])!r}",
                             field="time", expected="rows sorted by time")
