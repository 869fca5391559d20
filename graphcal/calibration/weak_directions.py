"""Directions of the calibration that the data cannot see, or see only weakly: found from the data,
held at their nominal value, named (solution remapping, Zhang, Kaess & Singh, ICRA 2016).

The parameters are the free intrinsics (n_fibres x 4, m and rad) and the extrinsic (rotation then
lever arm about body axes, rad and m), each scaled by its prior 1-sigma (the nominal model's stated
uncertainty: calibration/config.py "priors"), so that 1 is what the nominal model already knows. The
data's information in those units, W = S H_data S (trajectory corrections, when estimated, are
marginalised out: a Schur complement), has eigen-directions; one whose eigenvalue is below
WEAK_INFORMATION carries less information from the data than WEAK_INFORMATION times what the prior
carries. Along such a direction a fit moves with whatever biases the data term has (pairs re-made at
each estimate, normals tilted by noise, the INS's jitter: measured on a level head in a box street, one
Gauss-Newton step at the truth moved the lever arm's z by 4 m and the upper fibres' heights by 5-12 cm,
4-7 of their sigmas), so it is held at the nominal value instead: one factor (lock_factor) pins the
weak directions' coordinates, and the fit still moves along every other direction, so that what the
data do see of a weak parameter (the height of a ring on flat ground, a sum of its range offset,
elevation and height) is fitted. Whether a parameter is named unobservable is basis-free: the diagonal
of the projector onto the weak directions, its share of prior variance left to the weak directions
(1: the data see nothing of it; 1/2: it trades one-for-one with one other parameter; 1/31: it shares
a common mode with thirty others, which the priors together bound to 1/sqrt(31) of one prior sigma).
After the final fit the extrinsic's axes are judged once more by the sigmas that count each return's noise once
(seen_weakly): one they leave weak is held alone, a direction of its own.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import gtsam
import numpy as np

from graphcal.calibration.observability import (EXTRINSIC_NAMES, INTRINSIC_NAMES, NAMED_SHARE, Uncertainty, shown,
                                                tangent_to_axes)

# eigenvalue of the prior-whitened data information below which a direction is weak: the data carry
# less than this many times the prior's information along it (posterior sigma above 1/sqrt(1 + 10) ~
# 0.3 of the prior's)
WEAK_INFORMATION = 10.0
LOCK_SIGMA = 1e-4  # in prior sigmas: how tightly the lock factor holds a weak coordinate
UNION_ANGLE_DEG = 20.0  # a weak direction found again this close to one already held is the same one
COMPONENT_SHOWN = 0.3  # |component| of a weak direction for a parameter to be listed in another's reason


@dataclass(frozen=True)
class Layout:
    """Which keys a weak-direction analysis covers: the free intrinsic fibres (their keys, in order)
    and whether the extrinsic key is estimated; prior_sigma (P,) in the parameters' own units (m, rad;
    extrinsic about body axes); R_body_lidar of the nominal extrinsic (for the tangent <-> body axes)."""

    fibres: tuple[int, ...]
    extrinsic: bool
    prior_sigma: np.ndarray
    R_body_lidar: np.ndarray

    @property
    def names(self) -> list[str]:
        names = [f"fibre_{f}.{name}" for f in self.fibres for name in INTRINSIC_NAMES]
        return names + ([f"extrinsic.{name}" for name in EXTRINSIC_NAMES] if self.extrinsic else [])

    @property
    def size(self) -> int:
        return 4 * len(self.fibres) + (6 if self.extrinsic else 0)

    def tangent_from_whitened(self) -> np.ndarray:
        """(P, P) map from prior-whitened coordinates to the keys' tangent coordinates (intrinsic
        vectors as they are, the extrinsic's Pose3 tangent [w, v] in lidar axes)."""
        T = np.diag(self.prior_sigma)
        if self.extrinsic:
            k = 4 * len(self.fibres)
            T[k:, k:] = tangent_to_axes(self.R_body_lidar).T @ T[k:, k:]
        return T


@dataclass(frozen=True)
class WeakDirections:
    """The weak directions found (basis: (P, k) orthonormal columns in prior-whitened coordinates,
    with their eigenvalues) over a layout."""

    layout: Layout
    basis: np.ndarray
    eigenvalues: np.ndarray

    @classmethod
    def none(cls, layout: Layout) -> WeakDirections:
        return cls(layout, np.zeros((layout.size, 0)), np.zeros(0))

    @classmethod
    def of(cls, information: np.ndarray, layout: Layout, threshold: float = WEAK_INFORMATION) -> WeakDirections:
        """From the data's information (P, P) in the keys' tangent coordinates (no prior in it)."""
        T = layout.tangent_from_whitened()
        whitened = T.T @ information @ T
        eigenvalues, vectors = np.linalg.eigh(0.5 * (whitened + whitened.T))
        weak = eigenvalues < threshold
        return cls(layout, vectors[:, weak], eigenvalues[weak])

    @classmethod
    def along(cls, names: list[str], layout: Layout) -> WeakDirections:
        """The named parameters of the layout, each one weak direction of its own (eigenvalues unknown: NaN)."""
        columns = [layout.names.index(name) for name in names]
        return cls(layout, np.eye(layout.size)[:, columns], np.full(len(columns), np.nan))

    def union(self, other: WeakDirections) -> WeakDirections:
        """The span of both sets of weak directions (same layout); a direction of other within
        UNION_ANGLE_DEG of self's span is the same direction found again (the information changes a little
        between estimates), not a new one."""
        stacked = np.hstack([self.basis, other.basis])
        if stacked.shape[1] == 0:
            return self
        u, s, _ = np.linalg.svd(stacked, full_matrices=False)
        # stacked orthonormal bases: singular values sqrt(1 +- cos(angle)) per pair of principal directions
        keep = s ** 2 > 1.0 - np.cos(np.radians(UNION_ANGLE_DEG))
        eigenvalues = np.full(int(keep.sum()), np.nan)
        return WeakDirections(self.layout, u[:, keep], eigenvalues)

    def restricted(self, intrinsics: bool, extrinsic: bool) -> WeakDirections:
        """The weak directions that lie (mostly) within the intrinsics and/or the extrinsic: a stage that
        estimates one group holds what of them that group can move."""
        layout = self.layout
        fibres = layout.fibres if intrinsics else ()
        keep_extrinsic = extrinsic and layout.extrinsic
        rows = np.r_[np.arange(4 * len(fibres)), 4 * len(layout.fibres) + np.arange(6 if keep_extrinsic else 0)]
        rows = rows.astype(int)
        sub = Layout(fibres, keep_extrinsic, layout.prior_sigma[rows], layout.R_body_lidar)
        if not len(rows) or not self.basis.shape[1]:
            return WeakDirections.none(sub)
        u, s, _ = np.linalg.svd(self.basis[rows], full_matrices=False)
        within = s ** 2 > 0.5
        return WeakDirections(sub, u[:, within], np.full(int(within.sum()), np.nan))

    @property
    def share(self) -> np.ndarray:
        """(P,) each parameter's share of prior variance in the weak directions (projector diagonal)."""
        return np.einsum("pk,pk->p", self.basis, self.basis)

    def held_shares(self) -> dict[str, float]:
        """{parameter name: share} for every parameter with a share of its prior variance in the weak directions
        (their values there are the nominal's: Uncertainty.with_nominal_held)."""
        return {name: float(min(share, 1.0)) for name, share in zip(self.layout.names, self.share) if share > 1e-9}

    def named(self) -> dict[str, str]:
        """{parameter name: reason} for every parameter whose share exceeds NAMED_SHARE."""
        names, share = self.layout.names, self.share
        reasons = {}
        for p in np.flatnonzero(share > NAMED_SHARE):
            # the weak direction (within the span) most aligned with this parameter
            direction = self.basis @ self.basis[p] / np.sqrt(share[p])
            others = [names[q] for q in np.argsort(-np.abs(direction))
                      if q != p and abs(direction[q]) > COMPONENT_SHOWN][:4]
            if not others:
                reasons[names[p]] = "no pair of the recording constrains it beyond its prior"
            else:
                reasons[names[p]] = f"seen only in combination with {', '.join(others)}"
        return reasons

    def reset_to_nominal(self, offsets: np.ndarray, extrinsic: gtsam.Pose3,
                         nominal_extrinsic: gtsam.Pose3) -> tuple[np.ndarray, gtsam.Pose3]:
        """Offsets (n_fibres, 4) and extrinsic with their coordinates along the weak directions set back
        to the nominal's (zero offsets, nominal_extrinsic); the other coordinates kept."""
        if not self.basis.shape[1]:
            return offsets, extrinsic
        T = self.layout.tangent_from_whitened()
        x = tangent_about_nominal(self.layout, offsets, extrinsic, nominal_extrinsic)
        x = x - T @ (self.basis @ (self.basis.T @ np.linalg.solve(T, x)))
        offsets = offsets.copy()
        fibres = list(self.layout.fibres)
        offsets[fibres] = x[:4 * len(fibres)].reshape(-1, 4)
        if self.layout.extrinsic:
            extrinsic = nominal_extrinsic.retract(x[4 * len(fibres):])
        return offsets, extrinsic


def seen_weakly(sigmas: Uncertainty, layout: Layout, passed: set[str]) -> dict[str, str]:
    """{name: reason} for the extrinsic axes of the layout, but those passed, whose 1-sigma counting each return's
    noise once (sigmas, in file units: the final fit's shared_returns.py sigmas) is above the prior's over
    sqrt(1 + WEAK_INFORMATION): the data carry less than WEAK_INFORMATION times the prior's information on it once a
    return shared by many pairs counts once, though the model's information (WeakDirections.of) may see it better.
    With trajectory corrections estimated on a drive that does not revisit its track the lever arm is such an axis:
    the model's information, the corrections marginalised out, sees it more than ten times its prior, these sigmas
    several centimetres against a prior of 10 cm, and a fit that keeps it ended further from the truth than the
    nominal on six of eight foreign drives (docs/benchmarks.md); held, the corrections take up what it holds. The
    reported sigmas (the larger of these and the cluster-robust ones) hold the same axes on those drives and on a
    revisiting city loop; these judge because they do not rest on the residuals' own scatter, whose variance from
    the 30 time blocks of a 15 s drive is itself uncertain by a quarter (sqrt(2/29)). Not the intrinsics: a
    fibre's parameter held leaves in its ring's residuals what its data do see of it (judged so, a clean foreign
    recording's diagnosis found +0.8 cm on one fibre's pairs), where its fitted value lies within its sigma
    (accuracy.py names it imprecise)."""
    if not layout.extrinsic or sigmas.extrinsic is None:
        return {}
    names = layout.names[-len(EXTRINSIC_NAMES):]
    with np.errstate(invalid="ignore"):  # NaN (not estimated): not weak
        weak = sigmas.extrinsic > sigmas.extrinsic_prior / np.sqrt(1.0 + WEAK_INFORMATION)
    return {name: (f"seen weakly: the data determine it to {shown(name, sigma)} (1 sigma, each return's noise "
                   f"counted once) against its prior's {shown(name, prior)}, less than {WEAK_INFORMATION:g} times the "
                   "prior's information; held at its nominal value")
            for name, sigma, prior, w in zip(names, sigmas.extrinsic, sigmas.extrinsic_prior, weak)
            if w and name not in passed}


def tangent_about_nominal(layout: Layout, offsets: np.ndarray, extrinsic: gtsam.Pose3, nominal_extrinsic: gtsam.Pose3) -> np.ndarray:
    """(P,) tangent coordinates of the estimate about the nominal (zero offsets, nominal extrinsic)."""
    x = offsets[list(layout.fibres)].ravel()
    if layout.extrinsic:
        x = np.r_[x, nominal_extrinsic.localCoordinates(extrinsic)]
    return x


def lock_factor(weak: WeakDirections, intrinsic_keys: list[int], extrinsic_key: int | None,
                nominal_extrinsic: gtsam.Pose3) -> gtsam.CustomFactor | None:
    """One factor that holds the weak directions' coordinates at the nominal's (LOCK_SIGMA prior sigmas):
    residual B^T T^-1 x, x the tangent coordinates about the nominal (the extrinsic's the Logmap of
    nominal^-1 E, GTSAM's localCoordinates, with its exact Jacobian). None without weak directions."""
    if not weak.basis.shape[1]:
        return None
    layout = weak.layout
    A = weak.basis.T @ np.linalg.inv(layout.tangent_from_whitened()) / LOCK_SIGMA
    keys = list(intrinsic_keys) + ([extrinsic_key] if layout.extrinsic else [])
    noise = gtsam.noiseModel.Unit.Create(A.shape[0])
    return gtsam.CustomFactor(noise, keys, partial(_lock_error, A, len(intrinsic_keys), layout.extrinsic,
                                                   nominal_extrinsic))


def _lock_error(A: np.ndarray, n_intrinsic: int, extrinsic: bool, nominal: gtsam.Pose3, this: gtsam.CustomFactor,
                values: gtsam.Values, jacobians: list | None) -> np.ndarray:
    keys = this.keys()
    x = [values.atVector(keys[k]) for k in range(n_intrinsic)]
    if extrinsic:
        between = nominal.between(values.atPose3(keys[n_intrinsic]))
        x.append(gtsam.Pose3.Logmap(between))
    if jacobians is not None:
        for k in range(n_intrinsic):
            jacobians[k] = A[:, 4 * k:4 * k + 4]
        if extrinsic:
            jacobians[n_intrinsic] = A[:, 4 * n_intrinsic:] @ gtsam.Pose3.LogmapDerivative(between)
    return A @ np.concatenate(x)

