"""Which returns pair, and the local features they are judged by: features of the cloud (computed again
only when it has moved) and the association of one phase (its gates, its candidate p's). Plain arrays
in and out (calibration/association.py does the search)."""

from __future__ import annotations


from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from graphcal.calibration.association import (
    Correspondences,
    Features,
    PairCloud,
    PairGates,
    Sight,
    associate,
    local_features,
    neighbour_fibres,
)
from graphcal.calibration.config import AssociationSettings, FeatureSettings, PhaseGates
from graphcal.calibration.moving import without_moving
from graphcal.calibration.returns import ReturnData
from graphcal.calibration.tiles import Tiling

CANDIDATES_PER_PAIR = 5  # candidate p's of a fibre per pair drawn for each of its fibre pairs


def features_at(points_m: np.ndarray, settings: FeatureSettings, tiling: Tiling | None = None) -> Features:
    """local_features of the points [m] with the settings' radius, neighbours and voxel size (tile by tile with
    a tiling)."""
    if tiling is not None:
        return tiling.features(points_m, settings)
    return local_features(points_m, settings.radius_m, settings.neighbours, settings.voxel_m)


class FeatureCache:
    """The features of a calibration's cloud, computed again only once they may have changed by more
    than settings.refresh_above_m [m] (moved_m) since they were: the outer loop, the weak-direction
    analyses and the final fit share them (each computation is a neighbourhood search and an
    eigen-decomposition at every return), tile by tile with a tiling. It keeps the last pairs made too
    (pairs): a weak-direction analysis and the next solve, or the last one and the final fit, pair the same
    cloud."""

    def __init__(self, settings: FeatureSettings, tiling: Tiling | None = None):
        self.settings, self.tiling, self.points_m, self.features = settings, tiling, None, None
        self.estimate = None  # what the features were computed at (the caller's, e.g. a calibration's estimate)
        self.paired: tuple | None = None  # (the gates, the features, the points [m], the pairs)

    def pairs(self, association: Association, points_m: np.ndarray, fibre: np.ndarray, features: Features,
              gate_m: float, sight: Callable[[], Sight | None]) -> Correspondences:
        """association.pairs of the points [m] (their fibres) with these features at gate_m [m], the lines of
        sight made by sight() only when the pairs are made: the last pairs again when the same gates made them
        from the same points and features."""
        key = (association.gates, gate_m, association.moving is None)
        if (self.paired is not None and self.paired[0] == key and self.paired[1] is features
                and np.array_equal(self.paired[2], points_m)):
            return self.paired[3]
        pairs = association.pairs(points_m, fibre, features, gate_m, sight())
        self.paired = (key, features, points_m, pairs)
        return pairs

    def at(self, points_m: np.ndarray, estimate=None) -> tuple[Features, bool]:
        """(features for the points [m], whether they were computed now); estimate: what the points are of, kept
        with features computed now (self.estimate)."""
        if moved_m(points_m, self.points_m, self.settings.radius_m) <= self.settings.refresh_above_m:
            return self.features, False
        self.points_m, self.features = points_m, features_at(points_m, self.settings, self.tiling)
        self.estimate = estimate
        return self.features, True


def moved_m(points_m: np.ndarray, before_m: np.ndarray | None, radius_m: float) -> float:
    """How much the features of a cloud [m] may have changed since it was at before_m: the largest
    displacement of a point once the best rigid motion is removed (the shape's change), or the angle
    of that motion times radius_m (it turns the normals, seen over a neighbourhood of radius_m),
    whichever is larger. A common translation changes nothing; inf when there is no before, or
    another cloud."""
    if before_m is None or before_m.shape != points_m.shape:
        return np.inf
    now, then = points_m - points_m.mean(axis=0), before_m - before_m.mean(axis=0)
    rotation, _ = Rotation.align_vectors(now, then)  # now ~ R then (Kabsch)
    moved = now - rotation.apply(then)
    shape_m = float(np.sqrt(np.einsum("ni,ni->n", moved, moved).max(initial=0.0)))
    return max(shape_m, rotation.magnitude() * radius_m)


@dataclass(frozen=True)
class Association:
    """The association of one phase: its gates, each fibre's neighbouring fibres, the candidate p's
    (fixed across outer iterations), the seed of its draws, its tiling (None: the whole cloud at once) and
    the returns' acquisition times [s] with the settings that reject pairs seen on moving objects
    (graphcal.calibration.moving; None: none rejected)."""

    gates: PhaseGates
    neighbours: dict
    candidates: np.ndarray
    seed: int
    tiling: Tiling | None = None
    time_s: np.ndarray | None = None
    moving: AssociationSettings | None = None

    @classmethod
    def of(cls, data: ReturnData, gates: PhaseGates, neighbours: int, seed: int,
           tiling: Tiling | None = None, moving: AssociationSettings | None = None) -> Association:
        candidates = _candidates(data, CANDIDATES_PER_PAIR * gates.pairs_per_fibre_pair, np.random.default_rng(seed))
        return cls(gates, neighbour_fibres(data.sensor.elevation_deg, neighbours), candidates, seed, tiling,
                   data.time_s, moving)

    def pairs(self, points_m: np.ndarray, fibre: np.ndarray, features: Features, gate_m: float,
              sight: Sight | None) -> Correspondences:
        """The same subsample of pairs for the same cloud (a fresh seeded draw each time); sight: the
        returns' lines of sight and stand-ins (returns.sight_at), or None for plain nearest returns."""
        cloud, gates = PairCloud(points_m, fibre, features, sight), PairGates.of(self.gates, gate_m)
        if self.tiling is not None:
            pairs = self.tiling.associate(cloud, self.neighbours, gates, self.seed, self.candidates)
        else:
            pairs = associate(cloud, self.neighbours, gates, np.random.default_rng(self.seed), self.candidates)
        if self.moving is None:
            return pairs
        return without_moving(pairs, points_m, fibre, self.time_s, self.moving.moving_sigmas,
                              self.moving.moving_speed_m_s)


def _candidates(data: ReturnData, per_fibre: int, rng: np.random.Generator) -> np.ndarray:
    """Up to per_fibre random returns of each fibre: the p's of eq. 4.4."""
    rows = []
    for fibre in np.unique(data.fibre):
        of_fibre = np.flatnonzero(data.fibre == fibre)
        if len(of_fibre) > per_fibre:
            of_fibre = np.sort(rng.choice(of_fibre, per_fibre, replace=False))
        rows.append(of_fibre)
    return np.sort(np.concatenate(rows))
