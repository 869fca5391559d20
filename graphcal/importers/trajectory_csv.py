"""A user's CSV trajectory (any column names, degrees or radians, ENU or NED attitude) -> Trajectory.

`CsvTrajectoryFormat.columns` maps the contract's names onto the file's header: `time`, then
`lat, lon, alt` (geodetic, WGS 84, ellipsoidal height) or `x, y, z` (projected, metres in the
recording's CRS), then `roll, pitch, yaw` (attitude="enu": the recording's convention, FLU
body vs ENU or grid, yaw counter-clockwise from east) or `roll, pitch, heading`
(attitude="ned": an INS's FRD body vs NED, heading clockwise from north; converted as for SBET:
roll, -pitch, 90 deg - heading). Unmapped names are looked up under their own name.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from graphcal.common.errors import ConfigError
from graphcal.importers.sbet import ned_to_enu_attitude_deg
from graphcal.recording.rotations import unwrap_deg
from graphcal.common.tables import read_named_columns
from graphcal.recording.trajectory import Trajectory


@dataclass(frozen=True)
class CsvTrajectoryFormat:
    """How to read a trajectory CSV.

    columns: contract name -> column name in the file; position: 'geodetic' or 'projected';
    attitude: 'enu' or 'ned'; radians: angles (lat/lon and attitude) in radians instead of
    degrees; time_offset_s: added to the time column (e.g. to reach GPS seconds of week).
    """

    columns: dict[str, str] = field(default_factory=dict)
    position: str = "geodetic"
    attitude: str = "enu"
    radians: bool = False
    delimiter: str = ","
    time_offset_s: float = 0.0

    def __post_init__(self):
        if self.position not in ("geodetic", "projected"):
            raise ConfigError(f"position must be 'geodetic' or 'projected', not {self.position!r}")
        if self.attitude not in ("enu", "ned"):
            raise ConfigError(f"attitude must be 'enu' or 'ned', not {self.attitude!r}")
        unknown = sorted(set(self.columns) - {"time", "lat", "lon", "alt", "x", "y", "z", "roll", "pitch", "yaw",
                                              "heading"})
        if unknown:
            raise ConfigError(f"unknown trajectory field {unknown[0]!r} in the column mapping; known: time, lat, lon, "
                              "alt, x, y, z, roll, pitch, yaw (enu) or heading (ned)")

    @property
    def fields(self) -> tuple[str, ...]:
        position = ("lat", "lon", "alt") if self.position == "geodetic" else ("x", "y", "z")
        return ("time",) + position + ("roll", "pitch", "yaw" if self.attitude == "enu" else "heading")


def import_trajectory_csv(path: str | Path, fmt: CsvTrajectoryFormat | None = None) -> Trajectory:
    """Read a trajectory CSV; RecordingError naming the file, column and row of a bad value."""
    path, fmt = Path(path), fmt or CsvTrajectoryFormat()
    names = [fmt.columns.get(name, name) for name in fmt.fields]
    read = read_named_columns(path, names, fmt.delimiter)
    time, a, b, c, roll, pitch, third = (read[name] for name in names)
    to_deg = np.degrees if fmt.radians else np.asarray
    if fmt.attitude == "ned":
        rpy = ned_to_enu_attitude_deg(np.radians(to_deg(roll)), np.radians(to_deg(pitch)), np.radians(to_deg(third)))
    else:
        rpy = np.column_stack([to_deg(roll), to_deg(pitch), unwrap_deg(to_deg(third))])
    position = (np.column_stack([to_deg(a), to_deg(b), c]) if fmt.position == "geodetic"
                else np.column_stack([a, b, c]))
    trajectory = Trajectory(time=time + fmt.time_offset_s, position=position, rpy_deg=rpy,
                            geodetic=fmt.position == "geodetic")
    trajectory.validate(path)
    return trajectory
