"""Exceptions that name the file, the field or row, and what was expected."""

from __future__ import annotations

import math
from pathlib import Path


class GraphcalError(Exception):
    """Base class of every error graphcal raises on purpose."""


class RecordingError(GraphcalError):
    """Bad input in a recording: says which file, which column/field/row, what was expected."""

    def __init__(self, path: str | Path, problem: str, *, field: str | None = None,
                 row: int | None = None, expected: str | None = None):
        self.path, self.field, self.row, self.expected = Path(path), field, row, expected
        where = str(path)
        if field is not None:
            where += f", field '{field}'"
        if row is not None:
            where += f", row {row}"
        message = f"{where}: {problem}"
        if expected:
            message += f" (expected {expected})"
        super().__init__(message)


def finite_number(value, path: str | Path, field: str) -> float:
    """value as a float, or RecordingError naming the file and field when it is not a finite number."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise RecordingError(path, f"value {value!r}", field=field, expected="a finite number")
    return float(value)


class ConfigError(GraphcalError, ValueError):
    """Invalid user configuration (scenario, calibration settings)."""


class CalibrationError(GraphcalError):
    """A calibration that reached a wrong answer it can recognise (e.g. collapsed fibres)."""
