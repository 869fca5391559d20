"""A run folder: everything one command wrote, in one place (docs/reference/command-line.md).

    runs/<recording>-<command>-<UTC stamp>/    (or the folder given with --out)
        run.yaml       what ran (command line, recording, graphcal version, when) and the
                       seconds each stage took
        ...            the command's own files (calibration.yaml, run.rrd, report.html ...)
    runs/latest -> the last run written under runs/ (a symlink, as kiss-icp does)

Commands use it as

    run = RunFolder.create(out, recording.name, "calibrate")
    with run.stage("calibrate"):
        ...                                  # files written into run.path
    run.finish(recording=str(path))
    run.publish()                            # run.path becomes run.final, whole

A run is written into a hidden sibling folder (.<name>.partial-<host>-<pid>) and moved to its place only when complete,
so an interrupted run (even a SIGKILL) never leaves a folder that mixes a new calibration with an old report: a
re-run into an existing --out replaces it at the end, or leaves it as it was.
"""

from __future__ import annotations

import atexit
import datetime
import os
import re
import shutil
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from graphcal.common.atomic import remove_abandoned, working_tag
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
    final: Path
    latest: bool = False
    timings_s: dict[str, float] = field(default_factory=dict)
    created: str = field(default_factory=lambda: datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"))

    @classmethod
    def create(cls, out: Path | None, recording_name: str, command: str, root: Path = RUNS) -> RunFolder:
        """The folder `out`, or root/<recording>-<command>-<stamp> with root/latest pointing at it (the recording's
        name made a plain folder name: a name such as ../../x stays inside root)."""
        final = Path(out) if out is not None else root / f"{folder_name(recording_name)}-{command}-{utc_stamp()}"
        if final.exists() and not final.is_dir():
            raise ConfigError(f"{final}: --out names a file; a run folder is a directory")
        working = final.parent / f".{final.name}.partial-{working_tag()}"
        for kind in ("partial", "replaced"):  # what a killed run of the same folder left
            remove_abandoned(final.parent, f".{final.name}.{kind}-")
        if working.exists():
            shutil.rmtree(working)
        working.mkdir(parents=True)
        run = cls(working, command, final, latest=out is None)
        _UNPUBLISHED.append(run)
        return run

    def publish(self) -> Path:
        """Move the complete run to its place (replacing a previous run there) and point runs/latest at it. A
        recording inside the folder it replaces (the demo's out/recording, an input rather than a result) is kept."""
        if self.path != self.final:
            replaced = self.final.parent / f".{self.final.name}.replaced-{working_tag()}"
            if self.final.exists():
                for child in self.final.iterdir():
                    if (child / "recording.yaml").is_file() and not (self.path / child.name).exists():
                        os.replace(child, self.path / child.name)
                os.replace(self.final, replaced)
            os.replace(self.path, self.final)
            if replaced.exists():
                shutil.rmtree(replaced)
            self.path = self.final
        if self in _UNPUBLISHED:
            _UNPUBLISHED.remove(self)
        if self.latest:
            link_latest(self.final)
        return self.final

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


_UNPUBLISHED: list[RunFolder] = []


def abandon_unpublished() -> None:
    """Remove the working folders of runs that ended without publish (an error): what they had written is gone,
    the previous run at their place untouched. Also called at exit."""
    while _UNPUBLISHED:
        run = _UNPUBLISHED.pop()
        if run.path != run.final:
            shutil.rmtree(run.path, ignore_errors=True)


atexit.register(abandon_unpublished)


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
