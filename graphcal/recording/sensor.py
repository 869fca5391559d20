"""Nominal (factory) sensor model: sensor.yaml of RECORDING.md, and eq. 4.2 applied per fibre."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from factors.spherical import FactoryTerms, from_xyz, to_xyz_with_jacobian
from graphcal.common.errors import RecordingError, finite_number

OPTIONAL_FIBRE_FIELDS = ("azimuth_offset_deg", "range_offset_m", "vertical_offset_m",
                         "horizontal_offset_m", "height_offset_m")


@dataclass(frozen=True)
class FiringTiming:
    """When each laser fires: a firing cycle fires every fibre once, `laser_spacing_s` apart.

    Used by the simulator only; real recordings carry their own per-return times.
    """

    cycle_s: float
    laser_spacing_s: float


@dataclass(frozen=True, eq=False)
class SensorModel:
    """Nominal multi-beam model. Angles in degrees, lengths in metres, fibre id = row index.

    elevation_deg: phi_i of eq. 4.1; the optional factory terms default to zero.
    beam_origin_m: B, every beam's origin distance from the spin axis along the encoder direction
    (Ouster's lidar_origin_to_beam_origin_mm / 1000; 0 for Velodyne heads).
    """

    model: str
    rotation_hz: float
    reference_fibre: int
    elevation_deg: np.ndarray
    azimuth_offset_deg: np.ndarray
    range_offset_m: np.ndarray
    vertical_offset_m: np.ndarray
    horizontal_offset_m: np.ndarray
    height_offset_m: np.ndarray
    timing: FiringTiming | None = field(default=None, compare=False)
    beam_origin_m: float = 0.0

    @property
    def n_fibres(self) -> int:
        return len(self.elevation_deg)

    def factory_terms(self, fibre: np.ndarray) -> FactoryTerms:
        """Factory terms gathered per return (fibre: int array of fibre ids); a term that is zero on every fibre
        is the scalar 0 (most heads have no vertical or horizontal offset: eq. 4.2 then skips them per return)."""

        def gathered(per_fibre: np.ndarray) -> np.ndarray | float:
            return per_fibre[fibre] if np.any(per_fibre) else 0.0

        return FactoryTerms(
            elevation_rad=np.radians(self.elevation_deg)[fibre],
            azimuth_offset_rad=gathered(np.radians(self.azimuth_offset_deg)),
            range_offset_m=gathered(self.range_offset_m),
            vertical_offset_m=gathered(self.vertical_offset_m),
            horizontal_offset_m=gathered(self.horizontal_offset_m),
            height_offset_m=gathered(self.height_offset_m),
            beam_origin_m=self.beam_origin_m,
        )

    def to_xyz(self, fibre, range_m, azimuth_rad, offsets=None) -> np.ndarray:
        """Raw returns -> sensor-frame xyz [m] (eq. 4.2). offsets: (n_fibres, 4) per fibre."""
        xyz, _ = to_xyz_with_jacobian(range_m, azimuth_rad, self.factory_terms(fibre),
                                      self._per_return(fibre, offsets), jacobian=False,
                                      elevation_trig=self.elevation_trig(fibre, offsets))
        return xyz

    def elevation_trig(self, fibre, offsets=None) -> tuple[np.ndarray, np.ndarray]:
        """(cos e, sin e) of each return's elevation e = phi_i + d_phi (eq. 4.2), taken once per fibre and gathered
        (offsets: (n_fibres, 4) per fibre, None: zero)."""
        elevation = np.radians(self.elevation_deg) + (0.0 if offsets is None else np.asarray(offsets)[:, 2])
        return np.cos(elevation)[fibre], np.sin(elevation)[fibre]

    def to_xyz_with_jacobian(self, fibre, range_m, azimuth_rad, offsets=None):
        """xyz and d xyz / d (d_rho, d_theta, d_phi, Hz) per return, shapes (N,3), (N,3,4)."""
        return to_xyz_with_jacobian(range_m, azimuth_rad, self.factory_terms(fibre),
                                    self._per_return(fibre, offsets))

    def from_xyz(self, fibre, xyz, offsets=None):
        """Inverse of eq. 4.2: (range m, azimuth rad, off-cone distance m) per return."""
        return from_xyz(xyz, self.factory_terms(fibre), self._per_return(fibre, offsets))

    def with_offsets(self, offsets: np.ndarray) -> SensorModel:
        """This model with a calibration's offsets (n_fibres, 4; m, rad, rad, m) folded into its factory
        terms: the same points with zero offsets (exact where the laser has no vertical or horizontal
        offset, V_i = H_i = 0), a nominal model for the next calibration."""
        offsets = np.asarray(offsets, dtype=np.float64)
        if np.any(self.vertical_offset_m != 0) or np.any(self.horizontal_offset_m != 0):
            raise ValueError("offsets fold exactly only into a model without vertical and horizontal laser offsets")
        return replace(self, elevation_deg=self.elevation_deg + np.degrees(offsets[:, 2]),
                       azimuth_offset_deg=self.azimuth_offset_deg + np.degrees(offsets[:, 1]),
                       range_offset_m=self.range_offset_m + offsets[:, 0],
                       height_offset_m=self.height_offset_m + offsets[:, 3])

    def fibres_by_elevation(self) -> np.ndarray:
        """Fibre ids sorted from the lowest to the highest beam."""
        return np.argsort(self.elevation_deg, kind="stable")

    def _per_return(self, fibre, offsets):
        if offsets is None:
            return np.zeros(np.shape(fibre) + (4,))
        return np.asarray(offsets, dtype=np.float64)[fibre]

    # --- sensor.yaml --------------------------------------------------------------------
    def to_dict(self) -> dict:
        rows = []
        for i in range(self.n_fibres):
            row = {"id": i, "elevation_deg": float(self.elevation_deg[i])}
            for name in OPTIONAL_FIBRE_FIELDS:
                value = float(getattr(self, name)[i])
                if value != 0.0:
                    row[name] = value
            rows.append(row)
        head = {"model": self.model, "rotation_hz": float(self.rotation_hz),
                "reference_fibre": int(self.reference_fibre)}
        if self.beam_origin_m != 0.0:
            head["beam_origin_m"] = float(self.beam_origin_m)
        return head | {"fibres": rows}

    @classmethod
    def from_dict(cls, data: dict, path: str | Path = "sensor.yaml") -> SensorModel:
        """Parse sensor.yaml content, raising RecordingError naming the faulty field."""
        if not isinstance(data, dict):
            raise RecordingError(path, "not a mapping", expected="model, rotation_hz, reference_fibre, fibres")
        expected = {"model": "the sensor model name", "rotation_hz": "a rate in Hz",
                    "reference_fibre": "a fibre id", "fibres": "a list of {id, elevation_deg}"}
        for key, what in expected.items():
            if key not in data:
                raise RecordingError(path, "missing field", field=key, expected=what)
        unknown = sorted(set(data) - set(expected) - {"beam_origin_m"})
        if unknown:
            raise RecordingError(path, f"unknown field(s) {unknown}", field=unknown[0],
                                 expected=f"only {', '.join(expected)}, beam_origin_m")
        beam_origin_m = finite_number(data.get("beam_origin_m", 0.0), path, "beam_origin_m")
        if not isinstance(data["model"], str) or not data["model"]:
            raise RecordingError(path, f"model is {data['model']!r}", field="model", expected="the sensor model name")
        rotation_hz = finite_number(data["rotation_hz"], path, "rotation_hz")
        if not rotation_hz > 0:
            raise RecordingError(path, f"rotation_hz is {rotation_hz}", field="rotation_hz",
                                 expected="a positive rate in Hz")
        fibres = data["fibres"]
        if not isinstance(fibres, list) or not fibres:
            raise RecordingError(path, "no fibres", field="fibres", expected="a list of {id, elevation_deg}")
        columns = {name: np.zeros(len(fibres)) for name in ("elevation_deg",) + OPTIONAL_FIBRE_FIELDS}
        for row_index, row in enumerate(fibres):
            if not isinstance(row, dict) or row.get("id") != row_index:
                raise RecordingError(path, f"fibre row {row!r}", field="fibres", row=row_index,
                                     expected=f"id {row_index} (one row per laser, id = index)")
            if "elevation_deg" not in row:
                raise RecordingError(path, "missing elevation_deg", field="fibres", row=row_index,
                                     expected="the fibre's elevation in degrees")
            unknown = sorted(set(row) - {"id"} - set(columns))
            if unknown:
                raise RecordingError(path, f"unknown field(s) {unknown}", field="fibres", row=row_index,
                                     expected=f"id, {', '.join(columns)}")
            for name in columns:
                if name in row:
                    columns[name][row_index] = finite_number(row[name], path, f"fibres[{row_index}].{name}")
            if not -90.0 <= columns["elevation_deg"][row_index] <= 90.0:
                raise RecordingError(path, f"elevation_deg is {columns['elevation_deg'][row_index]}", field="fibres",
                                     row=row_index, expected="an elevation within -90..90 deg")
        values, counts = np.unique(columns["elevation_deg"], return_counts=True)
        if np.any(counts > 1):
            twice = int(np.argmax(counts > 1))
            rows = np.flatnonzero(columns["elevation_deg"] == values[twice])
            raise RecordingError(path, f"fibres {rows.tolist()} share the elevation {values[twice]} deg",
                                 field="fibres", row=int(rows[1]), expected="one elevation per laser")
        reference = data["reference_fibre"]
        if isinstance(reference, bool) or not isinstance(reference, int) or not 0 <= reference < len(fibres):
            raise RecordingError(path, f"reference_fibre is {reference!r}", field="reference_fibre",
                                 expected=f"a fibre id in 0..{len(fibres) - 1}")
        timing = CATALOG[data["model"]].timing if data["model"] in CATALOG else None
        return cls(model=str(data["model"]), rotation_hz=rotation_hz, reference_fibre=reference,
                   timing=timing, beam_origin_m=beam_origin_m, **columns)


def _make(model, elevation_deg, reference, timing, rotation_hz=10.0, **optional) -> SensorModel:
    n = len(elevation_deg)
    columns = {name: np.asarray(optional.get(name, np.zeros(n)), dtype=np.float64)
               for name in OPTIONAL_FIBRE_FIELDS}
    return SensorModel(model=model, rotation_hz=rotation_hz, reference_fibre=reference,
                       elevation_deg=np.asarray(elevation_deg, dtype=np.float64),
                       timing=timing, **columns)


# HDL-32E user manual: 32 lasers in firing order, -30.67 .. +10.67 deg in 4/3 deg steps,
# interleaved low/high; laser 15 is at 0 deg (the gauge of seed 000). One firing cycle every
# 46.08 us, lasers 1.152 us apart (manual, appendix E).
_HDL32_ELEVATION = [-30.67, -9.33, -29.33, -8.00, -28.00, -6.67, -26.67, -5.33, -25.33, -4.00,
                    -24.00, -2.67, -22.67, -1.33, -21.33, 0.00, -20.00, 1.33, -18.67, 2.67,
                    -17.33, 4.00, -16.00, 5.33, -14.67, 6.67, -13.33, 8.00, -12.00, 9.33,
                    -10.67, 10.67]
# VLP-16 user manual: -15 .. +15 deg in 2 deg steps, interleaved; 55.296 us cycle, 2.304 us apart.
_VLP16_ELEVATION = [-15, 1, -13, 3, -11, 5, -9, 7, -7, 9, -5, 11, -3, 13, -1, 15]


def _hdl64e() -> SensorModel:
    """A generic HDL-64E S2 factory model (per-unit tables differ; import a db.xml for real ones).

    Upper block (lasers 0-31): +2.0 .. -8.33 deg, vertical offset 0.20 m; lower block (32-63):
    -8.83 .. -24.33 deg, vertical offset 0.14 m. Horizontal offsets alternate +-2.6 cm and the
    azimuth offsets alternate with the laser's side of the head, the pattern of factory db.xml
    files. The whole head fires 64 lasers every 48 us (about 1.3 M returns/s at 10 Hz).
    """
    upper = np.linspace(2.0, -8.33, 32)
    lower = np.linspace(-8.83, -24.33, 32)
    side = np.where(np.arange(64) % 2 == 0, 1.0, -1.0)
    elevation = np.concatenate([upper, lower])
    return _make("HDL-64E", elevation, reference=int(np.argmin(np.abs(elevation))),
                 timing=FiringTiming(cycle_s=48e-6, laser_spacing_s=48e-6 / 64),
                 azimuth_offset_deg=-4.0 * side, vertical_offset_m=np.r_[np.full(32, 0.20), np.full(32, 0.14)],
                 horizontal_offset_m=0.026 * side)


CATALOG: dict[str, SensorModel] = {
    "HDL-32E": _make("HDL-32E", _HDL32_ELEVATION, reference=15,
                     timing=FiringTiming(cycle_s=46.08e-6, laser_spacing_s=1.152e-6)),
    "VLP-16": _make("VLP-16", _VLP16_ELEVATION, reference=int(np.argmin(np.abs(_VLP16_ELEVATION))),
                    timing=FiringTiming(cycle_s=55.296e-6, laser_spacing_s=2.304e-6)),
    "HDL-64E": _hdl64e(),
}


def sensor_from_catalog(model: str, rotation_hz: float = 10.0) -> SensorModel:
    """Nominal model of a known sensor ('HDL-32E', 'VLP-16', 'HDL-64E') spinning at rotation_hz."""
    if model not in CATALOG:
        raise KeyError(f"unknown sensor model {model!r}; known: {', '.join(CATALOG)}")
    base = CATALOG[model]
    return SensorModel(**{**base.__dict__, "rotation_hz": float(rotation_hz)})
