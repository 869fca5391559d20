"""Per-frame pose files: one 3x4 row-major matrix [R | t] per line (KITTI odometry, OpenCalib).

A line is either the 12 numbers (KITTI poses.txt: line i is frame i) or a frame name followed
by the 12 numbers (OpenCalib: `2021-10-26-16-21-29-468 r00 r01 r02 tx r10 ...`). The matrix
takes the frame's points to the pose frame: p_world = R p_frame + t [m].

A frame name that reads as a time gives the pose a time of its own: a number (s since 1970, or
ns when above 1e15) or a date and time `YYYY-MM-DD-HH-MM-SS[-fraction]` (any separators), read
on a clock of unknown zone (importers align it with the points' clock).
"""

from __future__ import annotations

import calendar
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from graphcal.common.errors import RecordingError

ROTATION_TOLERANCE = 1e-3  # largest |R^T R - I| of a pose's R (files print R to 6-9 digits)
MAX_TRANSLATION_M = 1e7  # [m] a pose frame is a local map frame, not the solar system
_DATE = re.compile(r"^(\d{4})\D(\d{2})\D(\d{2})\D(\d{2})\D(\d{2})\D(\d{2})(?:\D(\d+))?$")


@dataclass(frozen=True)
class FramePoses:
    """names: frame name per pose (None for KITTI's nameless lines); matrices: (N, 3, 4) [R | t], t in m."""

    names: list[str | None]
    matrices: np.ndarray


def read_frame_poses(path: str | Path) -> FramePoses:
    """Read a pose file; RecordingError naming the line of a malformed pose."""
    path = Path(path)
    if not path.is_file():
        raise RecordingError(path, "file not found")
    names, rows, lines = [], [], []
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        tokens = line.split()
        if not tokens or tokens[0].startswith("#"):
            continue
        name, numbers = (tokens[0], tokens[1:]) if len(tokens) == 13 else (None, tokens)
        try:
            values = [float(v) for v in numbers]
        except ValueError:
            values = []
        if len(values) != 12 or not np.all(np.isfinite(values)):
            raise RecordingError(path, f"{len(tokens)} fields {line[:60]!r}", row=number,
                                 expected="12 numbers (a 3x4 row-major [R | t]), optionally after a frame name")
        names.append(name)
        rows.append(values)
        lines.append(number)
    if not rows:
        raise RecordingError(path, "no pose", expected="one 3x4 row-major matrix per line")
    matrices = np.asarray(rows).reshape(-1, 3, 4)
    for number, matrix in zip(lines, matrices):
        problem = _not_a_pose(matrix)
        if problem:
            raise RecordingError(path, problem, row=number, expected=(
                f"R a rotation (R^T R = I within {ROTATION_TOLERANCE}, det R = +1) and |t| below "
                f"{MAX_TRANSLATION_M:g} m"))
    return FramePoses(names, matrices)


def _not_a_pose(matrix: np.ndarray) -> str | None:
    """What keeps a 3x4 [R | t] from being a pose, or None."""
    rotation, translation_m = matrix[:, :3], matrix[:, 3]
    if np.abs(rotation).max() > 1 + ROTATION_TOLERANCE:
        return f"R has an entry of {np.abs(rotation).max():.3g}"
    departure = np.abs(rotation.T @ rotation - np.eye(3)).max()
    if departure > ROTATION_TOLERANCE or np.linalg.det(rotation) < 0:
        return f"R is not a rotation (|R^T R - I| = {departure:.3g}, det R = {np.linalg.det(rotation):.3g})"
    if np.abs(translation_m).max() >= MAX_TRANSLATION_M:
        return f"t has a coordinate of {np.abs(translation_m).max():.3g} m"
    return None


def frame_time(name: str | None) -> float | None:
    """A frame name as a time [s] (see the module docstring), or None when it is not one."""
    if name is None:
        return None
    try:
        value = float(name)
    except ValueError:
        match = _DATE.match(name)
        if match is None:
            return None
        *fields, fraction = match.groups()
        whole = calendar.timegm(tuple(int(f) for f in fields) + (0, 0, 0))
        return whole + (float("0." + fraction) if fraction else 0.0)
    return value * 1e-9 if value > 1e15 else value
