"""The state the mismatch finder works on: a calibration fit (estimate, association, per-return
context) with the effects modelled so far, and its refit once an effect is added."""

from __future__ import annotations

from dataclasses import dataclass, replace

import gtsam
import numpy as np

from graphcal.calibration.association import Correspondences, Features
from graphcal.calibration.calibrate import calibrate
from graphcal.calibration.config import CalibrationConfig
from graphcal.calibration.observability import TRAJECTORY_GAUGE
from graphcal.calibration.problem import Estimate, ReturnData, pose_of, prepare, sight_at
from graphcal.calibration.result import CalibrationResult
from graphcal.calibration.solve import (
    Association,
    Priors,
    build_graph,
    energy_cm2,
    features_at,
    holding,
    levenberg_marquardt,
    read_back,
)
from graphcal.diagnosis.context import EffectModel, ReturnContext, world_with_effects
from graphcal.recording.directory import Recording

BLOCK_S = 0.5  # time blocks of the drive: clusters of correlated residuals, and the held-out split
VOXEL_M = 4.0


@dataclass(frozen=True)
class Fit:
    """A fit and what its tests need: the data, the estimate, the modelled effects (their values in
    model.values), the strict association at the estimate and the per-return context."""

    recording: Recording
    data: ReturnData
    config: CalibrationConfig
    estimated: tuple[bool, bool, bool]
    nominal: gtsam.Pose3
    priors: Priors
    estimate: Estimate
    model: EffectModel
    points_m: np.ndarray
    features: Features
    pairs: Correspondences

    @property
    def energy_cm2(self) -> float:
        return energy_cm2(self.points_m[self.pairs.index_p], self.points_m[self.pairs.index_m], self.pairs)[0]

    def clusters(self) -> tuple[np.ndarray, np.ndarray]:
        """Per pair: cluster id (time block x voxel of p) and half (parity of the time block)."""
        p = self.pairs.index_p
        block = np.floor((self.data.time_s[p] - self.data.time_s[0]) / BLOCK_S).astype(np.int64)
        voxel = np.floor(self.points_m[p] / VOXEL_M).astype(np.int64)
        _, cluster = np.unique(np.column_stack([block, voxel]), axis=0, return_inverse=True)
        return cluster.ravel(), block % 2

    def with_candidates(self, names: list[str]) -> EffectModel:
        """The model's effects plus candidates at zero, no priors (for linearising)."""
        values = dict(self.model.values) | {n: np.zeros(self.model.dim(n)) for n in names}
        return EffectModel(self.model.names + tuple(names), values, self.model.context)


def baseline(recording: Recording, config: CalibrationConfig, quiet: bool = True) -> tuple[Fit, CalibrationResult]:
    """Calibrate with the current model (no effect), then associate strictly at the estimate."""
    result = calibrate(recording, config, quiet=quiet)
    config = result.config  # with the settings calibrate resolved for the recording
    data = prepare(recording, config.control_interval_s, config.max_points, np.random.default_rng(config.seed),
                   range_noise_m=config.range_noise_m)
    priors = holding(Priors.of(config, data.sensor.n_fibres, len(data.control_times_s)),
                     [name for name in result.unobservable if name not in TRAJECTORY_GAUGE])
    fit = _associated(recording, data, config, result.estimated, pose_of(recording.extrinsic), priors,
                      result.calibration.estimate, None)
    return fit, result


def _associated(recording, data, config, estimated, nominal, priors, estimate, model) -> Fit:
    points = world_with_effects(data, estimate, config.pose_corrections, model)
    fine = config.fine()
    sight = sight_at(data, estimate, points)
    features = features_at(points, config)
    pairs = Association.of(data, fine).pairs(points, data.fibre, features, fine.fine_gate_m, fine, sight)
    if model is None:
        context = ReturnContext.of(data, recording.world.poses, points, features, estimate.extrinsic.translation())
        model = EffectModel((), {}, context)
    return Fit(recording, data, config, estimated, nominal, priors, estimate, model, points, features, pairs)


def refit(fit: Fit, names: tuple[str, ...], prior_sigma: dict, iterations: int = 4) -> Fit:
    """Re-solve with the effects `names` modelled (keys in every block, starting from the fit's values
    or zero): outer iterations of the fine phase (association at the current points, graph, LM)."""
    values = {n: fit.model.values.get(n, np.zeros(fit.model.dim(n))) for n in names}
    model = EffectModel(tuple(names), values, fit.model.context, prior_sigma)
    estimate, config = fit.estimate, fit.config
    fine = config.fine()
    association = Association.of(fit.data, fine)
    for _ in range(iterations):
        points = world_with_effects(fit.data, estimate, config.pose_corrections, model)
        sight = sight_at(fit.data, estimate, points)
        features = features_at(points, config)
        pairs = association.pairs(points, fit.data.fibre, features, fine.fine_gate_m, fine, sight)
        graph, initial = build_graph(fit.data, estimate, pairs, config, fit.estimated, fit.nominal, fit.priors,
                                     effects=model)
        solved = levenberg_marquardt(graph, initial, config.lm_iterations)
        estimate = read_back(solved, estimate, fit.estimated, fit.data, config.pose_corrections)
        model = replace(model, values=model.read(solved))
    return _associated(fit.recording, fit.data, config, fit.estimated, fit.nominal, fit.priors, estimate,
                       replace(model, prior_sigma=None))
