"""trajectory.csv of RECORDING.md: geodetic or projected GNSS/INS poses, read and written."""

from __future__ import annotations

import hashlib
import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from graphcal.common.errors import RecordingError
from graphcal.common.tables import read_csv_columns, write_csv_columns

GEODETIC_COLUMNS = ("time", "lat", "lon", "alt", "roll", "pitch", "yaw")
PROJECTED_COLUMNS = ("time", "x", "y", "z", "roll", "pitch", "yaw")

MAX_GRID_M = 1e8  # no map projection's easting or northing is larger (UTM: < 1e7)
MAX_HEIGHT_M = 1e5  # above the atmosphere, below the deepest mine: not a vehicle's height
# |lat| [deg], |lon| [deg], |height| [m] of a geodetic position
GEODETIC_LIMITS = (90.0, 180.0, MAX_HEIGHT_M)


@dataclass(frozen=True)
class Trajectory:
    """Body -> world poses as recorded.

    geodetic: position is (lat deg, lon deg, ellipsoidal height m) and attitude is relative to
    local East-North-Up; otherwise position is (x, y, z) m in the recording's CRS and attitude
    is relative to the grid axes. rpy_deg: roll, pitch, yaw [deg], yaw counter-clockwise from
    East (or grid x).
    """

    time: np.ndarray
    position: np.ndarray
    rpy_deg: np.ndarray
    geodetic: bool

    @property
    def columns(self) -> tuple[str, ...]:
        return GEODETIC_COLUMNS if self.geodetic else PROJECTED_COLUMNS

    def between(self, start: float, end: float) -> Trajectory:
        """The poses that cover [start, end] s: those inside plus the one before and the one after."""
        first = max(int(np.searchsorted(self.time, start, side="right")) - 1, 0)
        last = min(int(np.searchsorted(self.time, end, side="left")) + 1, len(self.time))
        return Trajectory(self.time[first:last], self.position[first:last], self.rpy_deg[first:last], self.geodetic)

    def save_csv(self, path: Path) -> None:
        """Write trajectory.csv; the times exactly (17 significant digits: a pose at a return's own time, as an
        importer may place one, still covers it when read back)."""
        write_csv_columns(path, self.columns, self._values(), formats=self._formats())

    def fingerprint(self) -> str:
        """A digest of the poses as trajectory.csv holds them: the same for this trajectory and for it written and
        read back."""
        buffer = io.BytesIO()
        np.savetxt(buffer, self._values(), delimiter=",", fmt=self._formats())
        return hashlib.sha256(buffer.getvalue()).hexdigest()

    def _values(self) -> np.ndarray:
        return np.column_stack([self.time, self.position, self.rpy_deg])

    def _formats(self) -> list[str]:
        return ["%.17g"] + ["%.10f" if self.geodetic else "%.6f"] * 2 + ["%.6f"] + ["%.8f"] * 3

    @classmethod
    def load_csv(cls, path: Path) -> Trajectory:
        """Read and validate: one of the two headers, finite numbers, strictly increasing time."""
        header, values = read_csv_columns(path, (GEODETIC_COLUMNS, PROJECTED_COLUMNS))
        trajectory = cls(time=values[:, 0], position=values[:, 1:4], rpy_deg=values[:, 4:7],
                         geodetic=header == GEODETIC_COLUMNS)
        trajectory.validate(path)
        return trajectory

    def validate(self, path: Path) -> None:
        """At least 2 poses, strictly increasing time, latitude/longitude (geodetic), grid coordinates and heights
        in range; RecordingError naming `path` and the 1-based row otherwise."""
        if len(self.time) < 2:
            raise RecordingError(path, f"{len(self.time)} pose(s)", expected="at least 2 poses to interpolate")
        bad = np.flatnonzero(np.diff(self.time) <= 0)
        if bad.size:
            row = int(bad[0]) + 2
            raise RecordingError(path, f"time {float(self.time[row - 1])!r} does not increase after "
                                       f"{float(self.time[row - 2])!r}",
                                 field="time", row=row, expected="strictly increasing times")
        limits = GEODETIC_LIMITS if self.geodetic else (MAX_GRID_M, MAX_GRID_M, MAX_HEIGHT_M)
        units = ("degrees", "degrees", "metres") if self.geodetic else ("metres",) * 3
        for name, column, limit, unit in zip(self.columns[1:4], self.position.T, limits, units):
            out = np.flatnonzero(np.abs(column) > limit)
            if out.size:
                raise RecordingError(path, f"value {float(column[out[0]])!r}", field=name, row=int(out[0]) + 1,
                                     expected=f"{unit} within +-{limit:g}")
