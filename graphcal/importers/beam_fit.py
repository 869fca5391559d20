"""Raw range, azimuth and fibre of Cartesian lidar points, through a nominal multi-beam model.

Importers of corrected point clouds (KITTI, PointCloud2, PCD) meet the same problem: the
driver turned raw (range, encoder azimuth) into sensor-frame x, y, z with its own per-laser
model, and the recording wants the raw values back. In the vertical plane of a return
(h = hypot(x, y), z), each fibre's beam is the line z cos e - h sin e = V (elevation e,
vertical offset V; the factory terms of eq. 4.2). This module

- fits that line to the points of one fibre (total least squares, outliers dropped);
- builds the nominal model of ringed clouds: the driver's model (a calibration file, its
  fibres matched to the rings by elevation order) or one line fitted per ring;
- inverts the model per return (`SensorModel.from_xyz`): range along the beam [m], encoder
  azimuth [rad, clockwise from x, 0..2 pi), and the distance of the point from its fibre's
  line [m], the misfit an import reports.

Frames: sensor frame x forward, y left, z up, as the driver wrote the points.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from graphcal.common.errors import RecordingError
from graphcal.importers.velodyne_calibration import VelodyneCalibration
from graphcal.recording.sensor import SensorModel

_FIT_ROUNDS = 3


def fit_beam_line(h_m: np.ndarray, z_m: np.ndarray, elevation_deg: float, vertical_m: float) -> tuple[float, float]:
    """One fibre's beam line (elevation deg, vertical offset m) refitted to its points (h, z) [m] by total least
    squares, without the points farther from the current line (elevation_deg, vertical_m) than 5 median distances."""
    points = np.column_stack([h_m, z_m])
    e = np.radians(elevation_deg)
    residual = np.abs(points[:, 1] * np.cos(e) - points[:, 0] * np.sin(e) - vertical_m)
    points = points[residual <= 5.0 * np.median(residual) + 1e-4]  # drop returns taken from crossing lines
    centre = points.mean(axis=0)
    direction = np.linalg.svd(points - centre, full_matrices=False)[2][0]
    direction *= np.sign(direction[0])  # along +h, away from the sensor
    elevation = float(np.degrees(np.arctan2(direction[1], direction[0])))
    e = np.radians(elevation)
    return elevation, float(centre[1] * np.cos(e) - centre[0] * np.sin(e))


def fit_ring_lines(xyz: np.ndarray, ring: np.ndarray, rings: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per ring of `rings`: (elevation deg, vertical offset m) of the line through its points, from the median
    elevation of its points (no offset) refined 3 times. xyz: (N, 3) sensor frame [m], ring: (N,) ring ids."""
    h_m, z_m = np.hypot(xyz[:, 0], xyz[:, 1]), xyz[:, 2]
    elevation, vertical = np.zeros(len(rings)), np.zeros(len(rings))
    for k, ring_id in enumerate(rings):
        mine = ring == ring_id
        h, z = h_m[mine], z_m[mine]
        elevation[k] = float(np.degrees(np.median(np.arctan2(z, h))))
        if len(h) < 3:
            continue
        for _ in range(_FIT_ROUNDS):
            elevation[k], vertical[k] = fit_beam_line(h, z, elevation[k], vertical[k])
    return elevation, vertical


@dataclass(frozen=True)
class RingModel:
    """The nominal model of a ringed cloud and how its rings map onto the model's fibres.

    fibre_of_ring: fibre id per ring id (index = ring id, -1 for a ring id not seen);
    notes: what was fitted or matched, in plain words."""

    sensor: SensorModel
    fibre_of_ring: np.ndarray
    notes: list[str]

    def fibres(self, ring: np.ndarray) -> np.ndarray:
        return self.fibre_of_ring[ring].astype(np.int16)

    def unknown_ring(self, ring: np.ndarray) -> int | None:
        """The first ring id of `ring` without a fibre in the model (one it was not fitted with), else None."""
        known = self.fibre_of_ring
        unknown = (ring < 0) | (ring >= len(known)) | (known[np.clip(ring, 0, len(known) - 1)] < 0)
        return int(ring[unknown][0]) if unknown.any() else None

    def raw(self, ring: np.ndarray, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(fibre, range m, encoder azimuth rad in [0, 2 pi), misfit m) of sensor-frame points xyz (N, 3) [m]."""
        fibre = self.fibres(ring)
        range_m, azimuth, off_line = self.sensor.from_xyz(fibre, np.asarray(xyz, dtype=np.float64))
        return fibre, range_m, azimuth, off_line


def ring_model(xyz: np.ndarray, ring: np.ndarray, model: str, rotation_hz: float, source,
               calibration: VelodyneCalibration | None = None) -> RingModel:
    """The nominal model of sensor-frame points xyz (N, 3) [m] with their ring ids (N,).

    With a calibration: its model, the rings matched to its fibres by elevation order (ring ids
    rising with the fitted elevation, as velodyne_pointcloud numbers them, or falling, as Ouster
    does). Without: one fibre per ring seen (in ring order), elevation and vertical offset fitted.
    source: the file named in errors."""
    ring = np.asarray(ring, dtype=np.int64)
    rings = np.unique(ring)
    if not len(rings):
        raise RecordingError(source, "no point", field="ring", expected="returns with their laser")
    elevation, vertical = fit_ring_lines(xyz, ring, rings)
    fibre_of_ring = np.full(int(rings[-1]) + 1, -1, dtype=np.int64)
    if calibration is None:
        fibre_of_ring[rings] = np.arange(len(rings))
        sensor = _fitted_model(model, rotation_hz, elevation, vertical)
        renumbered = "" if np.array_equal(rings, np.arange(len(rings))) else (
            f" (ring ids {rings.tolist()} renumbered 0..{len(rings) - 1})")
        notes = [f"nominal model FITTED to the points: one fibre per ring{renumbered}, its elevation and vertical "
                 "offset from a line through its points (no azimuth, range or horizontal offsets: a driver's "
                 "corrected points cannot show them, so a calibration estimates corrections to the driver's own "
                 "model, not the factory values)"]
        return RingModel(sensor, fibre_of_ring, notes)
    sensor = calibration.sensor
    rising = np.corrcoef(rings, elevation)[0, 1] >= 0 if len(rings) > 2 else elevation[-1] >= elevation[0]
    if rings[-1] >= sensor.n_fibres:
        raise RecordingError(source, f"ring id {int(rings[-1])}", field="ring",
                             expected=f"ring ids 0..{sensor.n_fibres - 1} for the {sensor.n_fibres} lasers of "
                                      f"{calibration.path.name}")
    by_elevation = sensor.fibres_by_elevation()
    fibre_of_ring[rings] = by_elevation[rings if rising else sensor.n_fibres - 1 - rings]
    worst = float(np.max(np.abs(elevation - sensor.elevation_deg[fibre_of_ring[rings]])))
    notes = [f"nominal model: {calibration.path.name}; ring r is the {'r-th lowest' if rising else 'r-th highest'} "
             f"beam (the rings' fitted elevations are {'rising' if rising else 'falling'} with the ring id); the "
             f"fitted elevations differ from the file's by at most {worst:.3f} deg"]
    notes.extend(calibration.notes())
    return RingModel(_with_rate(sensor, rotation_hz), fibre_of_ring, notes)


class MisfitSpread:
    """The model misfit |m| of any number of returns, counted in bins 1.2 % wide on a log scale from 0.1 µm to
    1 km: its quantiles (to the bin's upper edge) in fixed memory."""

    _EDGES_M = np.geomspace(1e-7, 1e3, 2001)

    def __init__(self):
        self._counts = np.zeros(len(self._EDGES_M) + 1, dtype=np.int64)

    def add(self, misfit_m: np.ndarray) -> None:
        bins = np.searchsorted(self._EDGES_M, np.abs(np.asarray(misfit_m, dtype=np.float64)))
        self._counts += np.bincount(bins, minlength=len(self._counts))

    def quantile_m(self, q: float) -> float:
        """The misfit [m] that a fraction q of the returns do not exceed (the top edge, 1 km, for any above it)."""
        index = int(np.searchsorted(np.cumsum(self._counts), q * self._counts.sum()))
        return float(self._EDGES_M[min(index, len(self._EDGES_M) - 1)])


def misfit_note(misfit: MisfitSpread) -> str:
    """The model misfit of an import, in plain words."""
    median_mm, top_mm = 1000 * misfit.quantile_m(0.5), 1000 * misfit.quantile_m(0.99)
    return (f"model misfit (distance of a point from its fibre's beam line): median {median_mm:.1f} mm, "
            f"99 % {top_mm:.1f} mm")


def _fitted_model(model: str, rotation_hz: float, elevation: np.ndarray, vertical: np.ndarray) -> SensorModel:
    zeros = np.zeros(len(elevation))
    elevation = elevation + 1e-9 * np.arange(len(elevation)) * (np.diff(np.sort(elevation)) == 0).any()
    return SensorModel(model=model, rotation_hz=rotation_hz, reference_fibre=int(np.argmin(np.abs(elevation))),
                       elevation_deg=elevation, azimuth_offset_deg=zeros, range_offset_m=zeros,
                       vertical_offset_m=vertical, horizontal_offset_m=zeros, height_offset_m=zeros)


def _with_rate(sensor: SensorModel, rotation_hz: float) -> SensorModel:
    return type(sensor)(**{**sensor.__dict__, "rotation_hz": float(rotation_hz)})
