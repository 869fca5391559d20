"""A rerun RecordingStream of its own per run (never the global one, so two runs in a process do
not mix) writing an .rrd file, and also a live viewer when asked."""

from __future__ import annotations

import os
import shutil
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import rerun as rr
import rerun.blueprint as rrb

from graphcal.common.atomic import atomic_path

APPLICATION_ID = "graphcal"
RRD = "run.rrd"
VIEWER_PORT = 9876
FLUSH_TIMEOUT_S = 10.0


def viewer_executable() -> str | None:
    """The `rerun` viewer installed with rerun-sdk next to this Python (a venv's bin/ is often
    not on PATH), else the one on PATH, else None."""
    beside = Path(sys.executable).parent / "rerun"
    return str(beside) if beside.is_file() else shutil.which("rerun")


def no_viewer_reason() -> str | None:
    """Why a native viewer cannot open here (no executable, no display), or None when it can."""
    if viewer_executable() is None:
        return "the rerun viewer executable is not installed (pip install rerun-sdk)"
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        return "no display (DISPLAY and WAYLAND_DISPLAY are unset)"
    return None


@contextmanager
def recording_stream(path: Path, name: str, spawn: bool = False) -> Iterator[rr.RecordingStream]:
    """A stream writing `path` (.rrd, atomically: it appears whole when the block ends without
    error); with spawn, a viewer is started and fed live too (a warning, not a failure, when it
    cannot be: the file is written either way). The log_* composers send their layout
    (send_layout) once they know where the data lies."""
    with atomic_path(path) as tmp:
        stream = rr.RecordingStream(APPLICATION_ID, recording_id=f"{name}-{Path(path).parent.name}")
        sinks = [rr.FileSink(str(tmp))]
        if spawn:
            reason = no_viewer_reason()
            if reason is None:
                rr.spawn(port=VIEWER_PORT, connect=False, executable_path=viewer_executable(), recording=stream)
                sinks.append(rr.GrpcSink(f"rerun+http://127.0.0.1:{VIEWER_PORT}/proxy"))
            else:
                print(f"warning: no live viewer, {reason}; writing {path} only", file=sys.stderr)
        stream.set_sinks(*sinks)
        stream.send_recording_name(name)
        try:
            yield stream
        finally:
            stream.flush(timeout_sec=FLUSH_TIMEOUT_S)
            stream.disconnect()


def send_layout(stream: rr.RecordingStream, blueprint: rrb.Blueprint) -> None:
    """Make `blueprint` the layout of the file (and of a live viewer) at once."""
    stream.send_blueprint(blueprint, make_active=True, make_default=True)
