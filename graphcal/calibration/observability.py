"""1-sigma of every estimated parameter from gtsam.Marginals (which parameters the data cannot see:
weak_directions.py).

The graph's cost is (W / sigma0^2) J + priors, so the marginal covariances are those of a
least-squares fit with point noise sigma0 (Cramér-Rao bound when sigma0 is the true noise).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, replace

import gtsam
import numpy as np
import scipy.linalg

from graphcal.recording.intrinsics import offsets_to_file_units

POSE_TO_FILE_UNITS = np.r_[np.full(3, np.degrees(1.0)), np.ones(3)]  # [rad x3, m x3] -> [deg x3, m x3]
INTRINSIC_NAMES = ("d_range_m", "d_azimuth_deg", "d_elevation_deg", "h_z_m")
EXTRINSIC_NAMES = ("roll_deg", "pitch_deg", "yaw_deg", "lever_arm_x_m", "lever_arm_y_m", "lever_arm_z_m")
TRAJECTORY_GAUGE = ("trajectory.common_translation", "trajectory.common_rotation")
CONTROL_NAMES = ("rotation_x_deg", "rotation_y_deg", "rotation_z_deg", "x_m", "y_m", "z_m")


@dataclass(frozen=True)
class Uncertainty:
    """Posterior and prior 1-sigma per parameter, in the file units of each name (m or deg):
    intrinsics (n_fibres, 4), NaN where not estimated; extrinsic (6,) as rotation about body
    x/y/z then lever arm in body axes, or None; control corrections (C, 6) as rotation about
    world x/y/z then translation (rotation columns NaN for translation-only), or None."""

    intrinsics: np.ndarray
    intrinsics_prior: np.ndarray
    extrinsic: np.ndarray | None
    extrinsic_prior: np.ndarray | None
    controls: np.ndarray | None
    controls_prior: np.ndarray | None

    def widest(self, other: Uncertainty) -> Uncertainty:
        """Each posterior sigma the larger of this one's and other's (same parameters, same priors)."""
        def wider(a, b):
            return None if a is None else np.fmax(a, b)

        return replace(self, intrinsics=wider(self.intrinsics, other.intrinsics),
                       extrinsic=wider(self.extrinsic, other.extrinsic), controls=wider(self.controls, other.controls))


class DenseMarginals:
    """Marginal covariances from the dense information matrix of the graph linearised at values,
    inverted scaled (dense_inverse): the fallback when gtsam.Marginals' Cholesky calls a graph
    "indeterminate" because its information spans many orders of magnitude (millimetre-sharp
    intrinsics next to a lever arm held only by its 1 m prior). Same interface as gtsam.Marginals
    (marginalCovariance(key)). Dense over every key: 130 + 6 per trajectory control, its cost the cube of
    that (docs/dev/open-questions.md)."""

    def __init__(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values):
        keys = list(values.keys())
        dims = [len(v) for v in (values.zeroVectors().at(k) for k in keys)]
        information, _ = graph.linearize(values).hessian(gtsam.Ordering(keys))
        self._of(information, dict(zip(keys, dims)))

    @classmethod
    def of(cls, information: np.ndarray, widths: dict[int, int]) -> DenseMarginals:
        """The marginals of a dense information matrix whose columns are the keys' tangent spaces, in order."""
        out = cls.__new__(cls)
        out._of(information, widths)
        return out

    def _of(self, information: np.ndarray, widths: dict[int, int]) -> None:
        self._information = information
        self._covariance = dense_inverse(information)
        self._right = None  # a sandwich's meat x covariance: its covariance is _covariance @ _right
        self._added = {}  # {key: variance added to its tangent coordinates' diagonal} (widened)
        starts = np.r_[0, np.cumsum(list(widths.values()))]
        self._span = {k: slice(a, b) for k, a, b in zip(widths, starts[:-1], starts[1:])}

    def marginalCovariance(self, key) -> np.ndarray:
        return self.jointCovariance(key, key)

    @property
    def width(self) -> int:
        """Columns of the information matrix: every key's tangent space."""
        return max(span.stop for span in self._span.values())

    def columns(self) -> dict[int, int]:
        """Each key's first column in the information matrix."""
        return {key: span.start for key, span in self._span.items()}

    def columns_of(self, key) -> np.ndarray:
        """The key's columns in the information matrix (its tangent coordinates, in order)."""
        return np.arange(self._span[key].start, self._span[key].stop)

    def jointCovariance(self, a, b) -> np.ndarray:
        """The covariance block of keys a (rows) and b (columns)."""
        if self._right is None:
            block = self._covariance[self._span[a], self._span[b]]
        else:
            block = self._covariance[self._span[a]] @ self._right[:, self._span[b]]
        return block + np.diag(self._added[a]) if a == b and a in self._added else block

    @property
    def information(self) -> np.ndarray:
        """H, the dense information matrix (the priors' included), in the columns of columns()."""
        return self._information

    @property
    def covariance(self) -> np.ndarray:
        """H^-1 in the columns of columns() (not a sandwich's, nor widened)."""
        return self._covariance

    def widened(self, variance: dict[int, np.ndarray]) -> DenseMarginals:
        """These marginals with variance[key] added to the diagonal of each given key's block."""
        out = copy.copy(self)
        out._added = {**self._added, **{key: self._added.get(key, 0.0) + v for key, v in variance.items()}}
        return out

    def sandwich(self, meat: np.ndarray) -> DenseMarginals:
        """The marginals of H^-1 meat H^-1 (a sandwich covariance on the same keys), each block made when asked
        for from H^-1 and meat H^-1: one product of the keys' size here instead of two."""
        out = copy.copy(self)
        out._right = meat @ self._covariance
        return out


def dense_inverse(information: np.ndarray) -> np.ndarray:
    """The inverse of a dense information matrix, scaled to a unit diagonal first: the information spans far
    more than 1/eps between parameters, but mostly through their units and priors, which the scaling takes out.
    By a Cholesky factor of the scaled matrix where its pivots stay above WELL_CONDITIONED (about 3x faster
    than an eigen-decomposition, and the inverse grows as the cube of the keys: 130 + 6 per trajectory
    control), else by eigen-decomposition with the eigenvalues floored at eps times the largest."""
    scale = 1.0 / np.sqrt(np.diag(information))
    scaled = information * np.outer(scale, scale)
    try:
        factor = scipy.linalg.cholesky(scaled, lower=True, check_finite=False)
        if np.min(np.diag(factor)) ** 2 < WELL_CONDITIONED:
            raise np.linalg.LinAlgError("pivots near rounding")
        inverse = scipy.linalg.cho_solve((factor, True), np.eye(len(scaled)), check_finite=False)
        inverse = (inverse + inverse.T) / 2
        if not np.all(np.diag(inverse) > 0):  # rounding beyond what the pivots showed
            raise np.linalg.LinAlgError("a variance at or below zero")
    except np.linalg.LinAlgError:
        eigenvalues, vectors = np.linalg.eigh(scaled)
        floor = eigenvalues.max() * np.finfo(float).eps
        inverse = (vectors / np.maximum(eigenvalues, floor)) @ vectors.T
    return np.outer(scale, scale) * inverse


WELL_CONDITIONED = 1e-10  # the smallest squared Cholesky pivot of a unit-diagonal matrix inverted by its factor


class Marginals:
    """gtsam.Marginals, switching to DenseMarginals for every key once GTSAM finds the system
    nearly indeterminate (in its constructor, or lazily when a covariance is asked for)."""

    def __init__(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values):
        self._graph, self._values = graph, values
        try:
            self._marginals = gtsam.Marginals(graph, values)
        except RuntimeError as error:
            self._marginals = self._dense_after(error)

    def marginalCovariance(self, key) -> np.ndarray:  # gtsam.Marginals' name
        try:
            return self._marginals.marginalCovariance(key)
        except RuntimeError as error:  # DenseMarginals never raises it: this switches once
            self._marginals = self._dense_after(error)
            return self._marginals.marginalCovariance(key)

    def _dense_after(self, error: RuntimeError) -> DenseMarginals:
        if "Indeterminate" not in str(error):
            raise error
        return DenseMarginals(self._graph, self._values)


def intrinsic_sigmas(marginals: gtsam.Marginals, key) -> np.ndarray:
    """(4,) sigmas of a Vector4 intrinsic key in file units (m, deg, deg, m)."""
    return offsets_to_file_units(np.sqrt(np.diag(marginals.marginalCovariance(key))))


def tangent_to_axes(R: np.ndarray) -> np.ndarray:
    """(6, 6) map of a Pose3 tangent [w, v] into the axes of R's output frame: GTSAM's retract
    perturbs R Exp(w), t + R v, so both parts turn by R (e.g. lidar -> body for T_body_lidar)."""
    rotate = np.zeros((6, 6))
    rotate[:3, :3] = rotate[3:, 3:] = R
    return rotate


def pose_sigmas(covariance_tangent: np.ndarray, R: np.ndarray) -> np.ndarray:
    """(6,) sigmas [deg x3, m x3] of a Pose3 whose tangent covariance is given, in the axes of
    R's output frame (see tangent_to_axes)."""
    rotate = tangent_to_axes(R)
    return np.sqrt(np.diag(rotate @ covariance_tangent @ rotate.T)) * POSE_TO_FILE_UNITS


TIE = 0.05  # relative: softest-direction components this close to the largest are a tie


def soft_parameters(information: np.ndarray, firm_sigma: np.ndarray) -> list[int]:
    """Indices of the parameters to hold so that every remaining one, and every combination of
    them, is determined to within firm_sigma by the data: the smallest eigenvalue of the
    information whitened by firm_sigma (information * outer(firm_sigma, firm_sigma)) is then
    at least 1. Greedy and pivoted: while the free set has a softer direction, hold the free
    parameter with the largest component along the softest direction (for a direction no pair
    sees, e.g. the common vertical offset of fibres that never pair with the reference fibre,
    this picks one of them, as choosing a reference fixes a gauge). Components within TIE of the
    largest are a tie, which the first of them wins: a common mode's components are equal up to
    rounding, and which one argmax found flipped the static halves check.

    information: (P, P) Gauss-Newton information of the data term (units of the parameters^-2);
    firm_sigma: (P,) the largest 1-sigma that counts as determined, in the parameters' units."""
    whitened = np.asarray(information, dtype=np.float64) * np.outer(firm_sigma, firm_sigma)
    free = list(range(len(firm_sigma)))
    held = []
    while free:
        eigenvalues, vectors = np.linalg.eigh(whitened[np.ix_(free, free)])
        if eigenvalues[0] >= 1.0:
            break
        component = np.abs(vectors[:, 0])
        held.append(free.pop(int(np.argmax(component >= (1.0 - TIE) * component.max()))))
    return sorted(held)
