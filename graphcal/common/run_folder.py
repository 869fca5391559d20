"""A run folder: everything one command wrote, in one place (docs/reference/command-line.md).

    runs/<recording>-<command>-<UTC stamp>/    (or the folder given with --out)
        run.yaml       what ran (command line, recording, graphcal version, when) and the
                       seconds each stage took
        ...            the command's own files (calibration.yaml, run.rrd, report.html ...)
    runs/latest -> the last run written under runs/ (a symlink, as kiss-icp does)

Commands use it as

    run = RunFolder.create(out, recording.name, "calibrate")
    with run.stage("calibrate"):
        ...
    run.finish(recording=str(path))
"""

from __future__ import annotations

import datetime
import os
import re
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from graphcal.common.errors import ConfigError, RecordingError
from graphcal.common.yamlfile import read_yaml, write_yaml

FORMAT = "graphcal-run/1"
RUNS = Path("runs")
MANIFEST = "run.yaml"
LATEST = "latest"


def folder_name(name: str) -> str:
    """A name as one plain path component: letters, digits, '.', '_' and '-' kept, anything else (a separator, a
    space) as '_', no leading dot (so neither '..' nor a hidden folder)."""
    plain = re.sub(r"[^A-Za-z0-9._-]", "_", name).lstrip(".")
    return plain or "recording"


def utc_stamp() -> str:
    """Now in UTC as 20260122T101500Z (sorts in time order, valid in file names)."""
    return datetime.datetime.now(datetime.UTC).strftime("%Y%m%dT%H%M%SZ")


@dataclass
class RunFolder:
    """The folder of one run and the seconds per stage it has measured so far (in order)."""

    path: Path
    command: str
    timings_s: dict[str, float] = field(default_factory=dict)
    created: str = field(default_factory=lambda: datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"))

    @classmethod
    def create(cls, out: Path | None, recording_name: str, command: str, root: Path = RUNS) -> RunFolder:
        """The folder `out`, or root/<recording>-<command>-<stamp> with root/latest pointing at it (the recording's
        name made a plain folder name: a name such as ../../x stays inside root)."""
        path = Path(out) if out is not None else root / f"{folder_name(recording_name)}-{command}-{utc_stamp()}"
        if path.exists() and not path.is_dir():
            raise ConfigError(f"{path}: --out names a file; a run folder is a directory")
        path.mkdir(parents=True, exist_ok=True)
        if out is None:
            link_latest(path)
        return cls(path, command)

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        """Time the block as stage `name` (seconds added up if the stage runs again)."""
        started = time.perf_counter()
        try:
            yield
        finally:
            self.timings_s[name] = self.timings_s.get(name, 0.0) + time.perf_counter() - started

    def finish(self, **fields) -> Path:
        """Write run.yaml: the command line, `fields` (recording path, ...) and the timings."""
        from graphcal import __version__

        manifest = {"format": FORMAT, "command": self.command, "argv": ["graphcal"] + sys.argv[1:],
                    "graphcal": __version__, "created": self.created, **fields,
                    "timings_s": {name: round(seconds, 3) for name, seconds in self.timings_s.items()}}
        write_yaml(self.path / MANIFEST, manifest)
        return self.path / MANIFEST


def read_manifest(folder: Path) -> dict:
    """run.yaml of a run folder (RecordingError naming it when absent or not a run's)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise RecordingError(folder, "run folder not found" if not folder.exists() else "not a folder")
    manifest = read_yaml(folder / MANIFEST)
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
        raise RecordingError(folder / MANIFEST, "not a graphcal run manifest", field="format", expected=FORMAT)
    return manifest


def link_latest(path: Path) -> None:
    """path.parent/latest -> path (relative), replaced atomically; skipped where symlinks fail."""
    link = path.parent / LATEST
    tmp = path.parent / f".{LATEST}.{os.getpid()}.tmp"
    try:
        if tmp.is_symlink():
            tmp.unlink()
        os.symlink(path.name, tmp)
        os.replace(tmp, link)
    except OSError:  # e.g. a file system without symlinks: the run folder is still complete
        if tmp.is_symlink():
            tmp.unlink()
