"""YAML files of the recording format: read with errors naming the file, written atomically."""

from __future__ import annotations

from pathlib import Path

import yaml

from graphcal.common.atomic import atomic_path
from graphcal.common.errors import RecordingError


def read_yaml(path: Path):
    """Parse a YAML file, or raise RecordingError naming it."""
    if not path.is_file():
        raise RecordingError(path, "file not found")
    try:
        return yaml.safe_load(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError as error:
        raise RecordingError(path, f"not a UTF-8 text file (byte {error.start}): YAML expected") from None
    except yaml.YAMLError as error:
        mark = getattr(error, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(error, "problem", None) or str(error).splitlines()[0]
        raise RecordingError(path, f"not valid YAML{where}: {problem}") from None


def write_yaml(path: str | Path, data) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(yaml.safe_dump(data, sort_keys=False, default_flow_style=None))
