"""The fields of one lidar scan (a PointCloud2 message, a PCD file) -> sensor-frame returns with absolute times.

Field names, as the common ROS drivers and PCD writers spell them:
- x, y, z: sensor frame [m] (x forward, y left, z up), any float type;
- intensity: optional (0 when absent), stored as it comes;
- ring (velodyne_pointcloud, Ouster, Hesai, OpenCalib) or channel (nebula): the laser's row;
- per-point time, the first of t (Ouster: uint32 ns), time (velodyne_pointcloud: float32 s),
  time_stamp (nebula: uint32 ns), timestamp (Hesai, OpenCalib: float64 s since 1970).
  Integer fields are read as nanoseconds, float fields as seconds (as nanoseconds when above
  1e12). Values above 1e8 s (1973) are absolute (s since 1970, UTC); smaller ones are offsets
  from the scan's stamp (the message header stamp, or the stamp in a PCD file's name).
Returns with a non-finite or all-zero x, y, z (no echo in an organised cloud) are left out.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from graphcal.common.errors import RecordingError

TIME_FIELDS = ("t", "time", "time_stamp", "timestamp")
RING_FIELDS = ("ring", "channel")
_ABSOLUTE_S = 1e8  # 1973: a smaller time is an offset from the scan's stamp
_NANOSECONDS = 1e12  # a float time above this is in ns (1e12 s is 30 000 years)


@dataclass(frozen=True)
class ScanPoints:
    """One scan's returns: xyz (N, 3) float64 m in the sensor frame, intensity (N,) float64 as stored,
    ring (N,) int64, time_s (N,) float64 s since 1970 UTC; time_note says how the time field was read."""

    xyz: np.ndarray
    intensity: np.ndarray
    ring: np.ndarray
    time_s: np.ndarray
    time_note: str


def scan_points(fields: np.ndarray, source: str | Path, stamp_s: float | None = None,
                stamp_what: str = "the scan's stamp") -> ScanPoints:
    """A structured array of one scan's points -> ScanPoints; RecordingError naming the missing field.

    stamp_s: the scan's stamp [s since 1970 UTC] that relative times count from (None: no stamp);
    stamp_what: what that stamp is, for the notes."""
    names = fields.dtype.names or ()
    for name in ("x", "y", "z"):
        if name not in names:
            raise RecordingError(source, f"no field {name!r} (fields: {', '.join(names)})", field=name,
                                 expected="x, y, z in the sensor frame")
    ring_name = next((n for n in RING_FIELDS if n in names), None)
    time_name = next((n for n in TIME_FIELDS if n in names), None)
    if ring_name is None:
        raise RecordingError(source, f"no ring field (fields: {', '.join(names)})", field="ring",
                             expected=f"the laser of each point in one of {', '.join(RING_FIELDS)}")
    if time_name is None:
        raise RecordingError(source, f"no per-point time field (fields: {', '.join(names)})", field="time",
                             expected=f"one of {', '.join(TIME_FIELDS)}")
    xyz = np.column_stack([fields[n].astype(np.float64) for n in ("x", "y", "z")])
    keep = np.all(np.isfinite(xyz), axis=1) & np.any(xyz != 0.0, axis=1)
    ring = fields[ring_name][keep]
    if ring.dtype.kind == "f":
        if not np.all(np.isfinite(ring) & (ring == np.round(ring)) & (ring >= 0)):
            raise RecordingError(source, "non-integer ring values", field=ring_name, expected="laser numbers 0, 1, ...")
    elif ring.dtype.kind not in "iu" or (len(ring) and ring.min() < 0):
        raise RecordingError(source, f"ring field of type {ring.dtype}", field=ring_name,
                             expected="non-negative laser numbers")
    time_s, note = _times(fields[time_name][keep], time_name, source, stamp_s, stamp_what)
    intensity = fields["intensity"][keep].astype(np.float64) if "intensity" in names else np.zeros(int(keep.sum()))
    return ScanPoints(xyz[keep], intensity, ring.astype(np.int64), time_s, note)


def _times(values: np.ndarray, name: str, source, stamp_s: float | None, stamp_what: str) -> tuple[np.ndarray, str]:
    """Per-point times -> (s since 1970 UTC, how they were read)."""
    kind, stored = values.dtype.kind, values.dtype
    if kind not in "iuf":
        raise RecordingError(source, f"time field of type {values.dtype}", field=name, expected="numbers")
    values = values.astype(np.float64)
    if not np.all(np.isfinite(values)):
        raise RecordingError(source, "non-finite per-point time", field=name, expected="finite times")
    if not len(values):
        return values, f"per-point time {name!r}"
    peak = float(np.max(np.abs(values)))
    in_ns = kind in "iu" or peak > _NANOSECONDS
    seconds = values * 1e-9 if in_ns else values
    unit = "ns" if in_ns else "s"
    if float(np.median(np.abs(seconds))) > _ABSOLUTE_S:
        return seconds, f"per-point time {name!r} ({stored}): absolute, {unit} since 1970 (UTC)"
    if stamp_s is None:
        raise RecordingError(source, f"per-point times up to {np.max(np.abs(seconds)):.3f} s are relative and the "
                                     "scan has no stamp", field=name,
                             expected="absolute times, or a stamp to count them from")
    return stamp_s + seconds, f"per-point time {name!r} ({stored}): {unit} relative to {stamp_what}"

