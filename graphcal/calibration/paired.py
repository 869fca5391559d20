"""Residuals before and after a calibration, on the same pairs: what the report's histograms and
the viewer's residual colours show.

The pairs are those the first outer iteration finds at the nominal calibration (same returns,
features, coarse settings, gate_start_m and seed as calibrate): their weighted mean square is
the J before the first solve of the history. Each pair's signed point-to-plane distance
n·(p_w - m_w) [m] (eq. 4.4, the normal n held as found at the nominal cloud) is evaluated at the
nominal and at the calibrated parameters.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from graphcal.association import local_features
from graphcal.atomic import atomic_path
from graphcal.calibration.evaluate import returns_for, world_of
from graphcal.calibration.problem import initial_estimate, world_at
from graphcal.calibration.result import CalibrationResult
from graphcal.calibration.solve import Association
from graphcal.errors import RecordingError
from graphcal.recording import Recording

FILE = "pairs_nominal.parquet"
_COLUMNS = ("row_p", "row_m", "weight", "before_m", "after_m", "x", "y", "z", "x_after", "y_after", "z_after")


@dataclass(frozen=True)
class PairedResiduals:
    """K pairs: rows of p and m in points.parquet, weight (planarity at p), signed residual [m]
    before (nominal) and after (calibrated), and p's world position [m, the recording's CRS]
    before and after (K,3)."""

    row_p: np.ndarray
    row_m: np.ndarray
    weight: np.ndarray
    before_m: np.ndarray
    after_m: np.ndarray
    p_before_m: np.ndarray
    p_after_m: np.ndarray

    def energy_cm2(self) -> tuple[float, float]:
        """J = sum w d^2 / sum w [cm^2] of these pairs, before and after."""
        total = float(self.weight.sum())
        return tuple(float((self.weight * d * d).sum() / total * 1e4) for d in (self.before_m, self.after_m))

    def save(self, folder: Path) -> Path:
        columns = {"row_p": self.row_p.astype(np.int64), "row_m": self.row_m.astype(np.int64),
                   "weight": self.weight.astype(np.float32), "before_m": self.before_m.astype(np.float32),
                   "after_m": self.after_m.astype(np.float32)}
        columns.update({name: self.p_before_m[:, k] for k, name in enumerate("xyz")})
        columns.update({f"{name}_after": self.p_after_m[:, k] for k, name in enumerate("xyz")})
        with atomic_path(Path(folder) / FILE) as tmp:
            pq.write_table(pa.table(columns), tmp, compression="zstd")
        return Path(folder) / FILE

    @classmethod
    def load(cls, folder: Path) -> PairedResiduals:
        path = Path(folder) / FILE
        if not path.is_file():
            raise RecordingError(path, "file not found", expected="the pairs graphcal calibrate writes")
        table = pq.read_table(path)
        missing = [name for name in _COLUMNS if name not in table.column_names]
        if missing:
            raise RecordingError(path, f"no column '{missing[0]}'", field=missing[0], expected=", ".join(_COLUMNS))
        column = {name: table.column(name).to_numpy() for name in _COLUMNS}
        return cls(column["row_p"], column["row_m"], column["weight"].astype(np.float64),
                   column["before_m"].astype(np.float64), column["after_m"].astype(np.float64),
                   np.column_stack([column[n] for n in "xyz"]),
                   np.column_stack([column[f"{n}_after"] for n in "xyz"]))


def paired_residuals(recording: Recording, result: CalibrationResult) -> PairedResiduals:
    """The nominal pairs of `result`'s first outer iteration, before and after (module docstring)."""
    config = result.config
    data = returns_for(result.calibration, recording, config.max_points, config.seed)  # calibrate's returns
    nominal = world_at(data, initial_estimate(recording, data), config.pose_corrections)
    features = local_features(nominal, config.feature_radius_m, config.feature_neighbours)
    pairs = Association.of(data, config).pairs(nominal, data.fibre, features, config.gate_start_m, config)
    p_before, m_before = nominal[pairs.index_p] + data.origin_m, nominal[pairs.index_m] + data.origin_m
    p_after, m_after = (world_of(result.calibration, data, rows) for rows in (pairs.index_p, pairs.index_m))
    return PairedResiduals(data.rows[pairs.index_p], data.rows[pairs.index_m], pairs.weight,
                           np.einsum("ni,ni->n", pairs.normal, p_before - m_before),
                           np.einsum("ni,ni->n", pairs.normal, p_after - m_after), p_before, p_after)
