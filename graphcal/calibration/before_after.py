"""Residuals before and after a calibration, measured the same way in both clouds: what the
report's histograms and the viewer's residual colours show.

In each cloud (nominal, calibrated) the returns the calibration used are paired as its first
outer iteration pairs them (same candidates, features at that cloud, the coarse gates at gate_start_m,
seed; the fine gates with association.fixed), and each pair's signed point-to-plane distance
n·(p_w - m_w) [m] (eq. 4.4) is taken. In the nominal cloud these are exactly the first iteration's pairs: their weighted mean square is the
history's first J. The coarse settings cut nothing on the distance to the plane, so the blur of
the nominal cloud shows whole; they also keep some pairs across edges, which leave about 0.3 cm²
of J even at the true calibration (docs/reference/math.md).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from graphcal.calibration.evaluate import nominal_calibration, returns_for, world_of
from graphcal.calibration.priors import Priors
from graphcal.calibration.problem import Problem
from graphcal.calibration.result import Calibration, CalibrationResult
from graphcal.calibration.returns import pose_of
from graphcal.common.atomic import atomic_path
from graphcal.common.errors import RecordingError
from graphcal.recording.directory import Recording

FILES = {"before": "pairs_nominal.parquet", "after": "pairs_calibrated.parquet"}
_COLUMNS = ("row_p", "row_m", "weight", "residual_m", "x", "y", "z")


@dataclass(frozen=True)
class Pairs:
    """K pairs of one cloud: rows of p and m in points.parquet, weight (planarity at p), signed
    residual [m], and p's world position (K,3) [m, the recording's CRS]."""

    row_p: np.ndarray
    row_m: np.ndarray
    weight: np.ndarray
    residual_m: np.ndarray
    p_m: np.ndarray

    def energy_cm2(self) -> float:
        """J = sum w d^2 / sum w [cm^2]."""
        return float((self.weight * self.residual_m ** 2).sum() / self.weight.sum() * 1e4)

    def save(self, path: Path) -> Path:
        columns = {"row_p": self.row_p.astype(np.int64), "row_m": self.row_m.astype(np.int64),
                   "weight": self.weight.astype(np.float32), "residual_m": self.residual_m.astype(np.float32)}
        columns.update({name: self.p_m[:, k] for k, name in enumerate("xyz")})
        with atomic_path(path) as tmp:
            pq.write_table(pa.table(columns), tmp, compression="zstd")
        return Path(path)

    @classmethod
    def load(cls, path: Path) -> Pairs:
        if not Path(path).is_file():
            raise RecordingError(path, "file not found", expected="the pairs graphcal calibrate writes")
        table = pq.read_table(path)
        missing = [name for name in _COLUMNS if name not in table.column_names]
        if missing:
            raise RecordingError(path, f"no column '{missing[0]}'", field=missing[0], expected=", ".join(_COLUMNS))
        column = {name: table.column(name).to_numpy() for name in _COLUMNS}
        return cls(column["row_p"], column["row_m"], column["weight"].astype(np.float64),
                   column["residual_m"].astype(np.float64), np.column_stack([column[n] for n in "xyz"]))


@dataclass(frozen=True)
class BeforeAfter:
    """The pairs of the nominal cloud (before) and of the calibrated cloud (after)."""

    before: Pairs
    after: Pairs

    def save(self, folder: Path) -> None:
        self.before.save(Path(folder) / FILES["before"])
        self.after.save(Path(folder) / FILES["after"])

    @classmethod
    def load(cls, folder: Path) -> BeforeAfter:
        return cls(*(Pairs.load(Path(folder) / FILES[which]) for which in ("before", "after")))


def residuals_before_after(recording: Recording, result: CalibrationResult) -> BeforeAfter:
    """The pairs and residuals of the nominal and of the calibrated cloud (module docstring)."""
    config = result.config
    # calibrate's returns, and its range noise: the same choice of m as the first outer iteration's
    data = returns_for(result.calibration, recording, config.max_points, config.seed, config.weighting.range_noise_m)
    problem = Problem(data, config, result.estimated, pose_of(recording.extrinsic),
                      Priors.of(config, data.sensor.n_fibres, len(data.control_times_s)))
    problem = problem.in_phase("fine" if config.association.fixed else "coarse")  # fixed: fine only
    return BeforeAfter(*(pairs_in(problem, calibration) for calibration in (nominal_calibration(recording),
                                                                            result.calibration)))


def pairs_in(problem: Problem, calibration: Calibration) -> Pairs:
    """The first outer iteration's association (the gates and choice of m of its phase) in the cloud of
    `calibration`."""
    data = problem.data
    points = world_of(calibration, data) - data.origin_m
    pairs = replace(problem, fixed_pairs=None).associate(calibration.estimate, points)
    residual = np.einsum("ni,ni->n", pairs.normal, points[pairs.index_p] - points[pairs.index_m])
    return Pairs(data.rows[pairs.index_p], data.rows[pairs.index_m], pairs.weight, residual,
                 points[pairs.index_p] + data.origin_m)
