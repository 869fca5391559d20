"""Numeric CSV tables with a fixed header (trajectory.csv, odometry.csv, truth CSVs)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv

from graphcal.common.atomic import atomic_path
from graphcal.common.errors import RecordingError


def read_csv_columns(path: Path, headers: Sequence[Sequence[str]],
                     optional: Sequence[str] = ()) -> tuple[tuple[str, ...], np.ndarray]:
    """Read a CSV whose header is one of `headers` (plus any of `optional`) into float64.

    Returns (header actually found, values (rows, columns)). Raises RecordingError naming the
    file, the column and the 1-based data row of the first bad value.
    """
    path = Path(path)
    table = _read_table(path)
    names = tuple(table.column_names)
    header = next((tuple(h) for h in headers if tuple(n for n in names if n not in optional) == tuple(h)), None)
    if header is None:
        expected = " or ".join(",".join(h) for h in headers)
        # name what differs from the closest of the accepted headers
        closest = min(headers, key=lambda h: sum(c not in names for c in h))
        missing = [c for c in closest if c not in names]
        unexpected = [n for n in names if n not in closest and n not in optional]
        problem = (f"header is {','.join(names)}" + (f"; missing column '{missing[0]}'" if missing else "")
                   + (f"; unexpected column '{unexpected[0]}'" if unexpected and not missing else ""))
        raise RecordingError(path, problem, expected=f"header {expected}"
                             + (f" (optional: {','.join(optional)})" if optional else ""))
    found = header + tuple(n for n in optional if n in names)
    columns = [_float_column(path, name, table.column(name)) for name in found]
    return found, np.column_stack(columns) if columns else np.empty((0, 0))


def read_named_columns(path: Path, names: Sequence[str], delimiter: str = ",") -> dict[str, np.ndarray]:
    """The named columns of a CSV with any header (other columns ignored) as float64 arrays.

    Raises RecordingError naming the file and the missing column, or the column and 1-based
    data row of the first value that is not a finite number."""
    path = Path(path)
    table = _read_table(path, delimiter)
    missing = [name for name in names if name not in table.column_names]
    if missing:
        raise RecordingError(path, f"no column '{missing[0]}' in the header {delimiter.join(table.column_names)}",
                             field=missing[0], expected="a column of that name")
    return {name: _float_column(path, name, table.column(name)) for name in names}


def _read_table(path: Path, delimiter: str = ",") -> pa.Table:
    if not path.is_file():
        raise RecordingError(path, "file not found")
    try:
        # only an empty cell is missing: 'nan', 'NULL', 'N/A' ... are values, rejected by name later
        return pacsv.read_csv(path, parse_options=pacsv.ParseOptions(delimiter=delimiter),
                              convert_options=pacsv.ConvertOptions(null_values=[""]))
    except (pa.ArrowInvalid, OSError) as error:
        raise RecordingError(path, f"not a readable CSV: {error}") from None


def _float_column(path: Path, name: str, column: pa.ChunkedArray) -> np.ndarray:
    if column.null_count:
        row = int(np.flatnonzero(column.is_null().to_numpy(zero_copy_only=False))[0])
        raise RecordingError(path, "empty value", field=name, row=row + 1, expected="a number")
    if not (pa.types.is_floating(column.type) or pa.types.is_integer(column.type)):
        for row, value in enumerate(column.to_pylist()):
            try:
                float(value)
            except (TypeError, ValueError):
                raise RecordingError(path, f"value {value!r}", field=name, row=row + 1,
                                     expected="a number") from None
    values = column.to_numpy(zero_copy_only=False).astype(np.float64)
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        raise RecordingError(path, f"value {float(values[bad[0]])!r}", field=name, row=int(bad[0]) + 1,
                             expected="a finite number")
    return values


def write_csv_columns(path: Path, header: Sequence[str], values: np.ndarray,
                      formats: Sequence[str] | str = "%.9g") -> None:
    """Write a numeric table atomically with a header line."""
    with atomic_path(path) as tmp:
        np.savetxt(tmp, values, delimiter=",", header=",".join(header), comments="", fmt=formats)
