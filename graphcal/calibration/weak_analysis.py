"""The weak directions of a calibration at an estimate, from its pairs (weak_directions.py holds what
they are and how they are held)."""

from __future__ import annotations

import gtsam
import numpy as np

from graphcal.calibration.association import Correspondences
from graphcal.calibration.config import CalibrationConfig
from graphcal.calibration.problem import Estimate, ReturnData
from graphcal.calibration.solve import (
    E,
    I,
    X,
    Priors,
    add_priors,
    add_trajectory,
    control_prior_sigma,
    make_blocks,
    make_factor,
)
from graphcal.calibration.weak_directions import Layout, WeakDirections


def layout_of(data: ReturnData, priors: Priors, estimated: tuple[bool, bool, bool],
              nominal_extrinsic: gtsam.Pose3) -> Layout:
    """The parameters a weak-direction analysis covers: the intrinsics of every fibre but the reference
    (when estimated) and the extrinsic (when estimated), with their prior sigmas."""
    fibres = tuple(f for f in range(data.sensor.n_fibres) if f != data.sensor.reference_fibre) if estimated[0] else ()
    sigma = np.r_[priors.intrinsic[list(fibres)].ravel(), priors.extrinsic if estimated[1] else np.zeros(0)]
    return Layout(fibres, estimated[1], sigma, nominal_extrinsic.rotation().matrix())


def weak_at(data: ReturnData, estimate: Estimate, pairs: Correspondences, config: CalibrationConfig,
            estimated: tuple[bool, bool, bool], priors: Priors, layout: Layout) -> WeakDirections:
    """The weak directions of the data's information at the estimate, on these pairs."""
    if not layout.size:
        return WeakDirections.none(layout)
    keys = [I(f) for f in layout.fibres] + ([E(0)] if layout.extrinsic else [])
    return WeakDirections.of(data_information(data, estimate, pairs, config, estimated, priors, keys), layout)


def data_information(data: ReturnData, estimate: Estimate, pairs: Correspondences, config: CalibrationConfig,
                     estimates: tuple[bool, bool, bool], priors: Priors, keys: list[int]) -> np.ndarray:
    """The Gauss-Newton information (in the keys' tangent coordinates) that the pairs alone carry on the
    given keys (intrinsic and extrinsic keys), the trajectory corrections, when estimated, marginalised
    out with their own priors (E_def, held components): no prior on the calibration's keys is in it."""
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for _, block in make_blocks(data, estimate, pairs, config, estimates):
        graph.add(make_factor(block))
    add_priors(gtsam.NonlinearFactorGraph(), values, data, estimate, config, estimates, estimate.extrinsic, priors,
                False, float(pairs.weight.sum()))
    controls = []
    if estimates[2]:
        controls = [X(c) for c in range(len(estimate.corrections))]
        add_trajectory(graph, gtsam.Values(), estimate, config, control_prior_sigma(config, float(pairs.weight.sum())),
                        priors, False)
    ordering = list(keys) + controls
    widths = {key: values.zeroVectors().at(key).size for key in ordering}
    present = set(graph.keys())
    reached = [key for key in ordering if key in present]
    reached_information, _ = graph.linearize(values).hessian(gtsam.Ordering(reached))
    starts = np.r_[0, np.cumsum([widths[key] for key in ordering])]
    spans = {key: np.arange(a, b) for key, a, b in zip(ordering, starts[:-1], starts[1:])}
    columns = np.concatenate([spans[key] for key in reached]) if reached else np.zeros(0, int)
    information = np.zeros((starts[-1], starts[-1]))
    information[np.ix_(columns, columns)] = reached_information
    # a control no pair reaches keeps only its own prior: invertible for the Schur complement
    information[starts[len(keys)]:, starts[len(keys)]:] += np.eye(starts[-1] - starts[len(keys)]) * 1e-12
    return schur_complement(information, information.shape[0] - (6 if config.pose_corrections else 3) * len(controls))


def schur_complement(information: np.ndarray, keep: int) -> np.ndarray:
    """The information on the first `keep` coordinates once the others are marginalised out."""
    if keep == len(information):
        return information
    a, b, c = information[:keep, :keep], information[:keep, keep:], information[keep:, keep:]
    return a - b @ np.linalg.solve(c, b.T)
