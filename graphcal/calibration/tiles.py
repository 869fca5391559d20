"""Features and association (eq. 4.4's pairs) tile by tile of space, so that a TaskMap
(graphcal.common.cluster) can spread them over worker processes or a Dask cluster while the factor graph
stays on the driver.

The cloud's plan (x, y in the world frame minus the local origin [m]) is cut into squares of tile_m; a tile's
core are the returns inside its square, its halo the core and every return within margin_m of the square.
Each tile computes the features of its core from its halo (exact when margin_m covers twice the features'
radius: a neighbourhood never leaves the halo, nor does that of a neighbour whose plane a voxel mean takes,
association.least_bent) and pairs its core's candidate p's with returns of its halo (every m
within the gate is in the halo when margin_m covers the gate and the stand-ins' reach). Passes of the same
street at different times fall in the same tile: their pairs tie the trajectory corrections of both passes.
A tile's random draws come from the seed and the tile's own position: the result does not depend on where,
or in which order, the tiles run.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import numpy as np

from graphcal.calibration.association import (
    PROXY_REACH_M,
    Correspondences,
    Features,
    PairCloud,
    PairGates,
    associate,
    local_features,
    voxel_corner,
)
from graphcal.calibration.config import AssociationSettings, FeatureSettings
from graphcal.common.cluster import IN_PROCESS, TaskMap


@dataclass(frozen=True)
class Tile:
    """One square of the plan: its integer position (key), its core rows and its halo rows (sorted), and where
    the core rows sit in the halo."""

    key: tuple[int, int]
    core: np.ndarray
    halo: np.ndarray
    core_in_halo: np.ndarray


@dataclass(frozen=True)
class Tiling:
    """Squares of tile_m [m] with halos of margin_m [m] (module docstring), their work run by task_map."""

    tile_m: float
    margin_m: float
    task_map: TaskMap = IN_PROCESS
    # the last cloud's tiles (an outer iteration cuts the same cloud for its features and for its pairs)
    _last: list = field(default_factory=list, compare=False, repr=False)

    def __post_init__(self):
        if not 0 < self.margin_m < self.tile_m:
            raise ValueError(f"tiles of {self.tile_m} m need a margin in (0, {self.tile_m}) m, not {self.margin_m}")

    @classmethod
    def of(cls, association: AssociationSettings, features: FeatureSettings, task_map: TaskMap = IN_PROCESS):
        """The tiling association.tile_m asks for (None: none), with a margin covering twice the features'
        radius, the widest gate of either phase and a stand-in's reach on both sides of a pair."""
        if association.tile_m is None:
            return None
        reach_m = max(2 * features.radius_m, association.coarse.gate_max_m, association.fine.gate_max_m)
        return cls(association.tile_m, reach_m + 2 * PROXY_REACH_M, task_map)

    def tiles(self, points_m: np.ndarray) -> list[Tile]:
        """The tiles that hold returns, in key order (kept for the last cloud cut: the same array object)."""
        if self._last and self._last[0] is points_m:
            return self._last[1]
        key = np.floor(points_m[:, :2] / self.tile_m).astype(np.int64)
        order = np.lexsort((key[:, 1], key[:, 0]))
        keys, starts = np.unique(key[order], axis=0, return_index=True)
        rows_of = {tuple(k): np.sort(order[a:b]) for k, a, b in zip(keys.tolist(), starts, np.r_[starts[1:], len(order)])}
        out = []
        for (kx, ky), core in rows_of.items():
            near = np.concatenate([rows_of.get((kx + dx, ky + dy), np.zeros(0, np.int64))
                                   for dx in (-1, 0, 1) for dy in (-1, 0, 1)])
            lo = np.array([kx, ky]) * self.tile_m - self.margin_m
            hi = lo + self.tile_m + 2 * self.margin_m
            xy = points_m[near, :2]
            halo = np.sort(near[np.all((xy >= lo) & (xy < hi), axis=1)])
            out.append(Tile((kx, ky), core, halo, np.searchsorted(halo, core)))
        self._last[:] = [points_m, out]
        return out

    def features(self, points_m: np.ndarray, settings: FeatureSettings) -> Features:
        """local_features of every point, tile by tile (voxels on the whole cloud's grid)."""
        tiles = self.tiles(points_m)
        corner_m = voxel_corner(points_m, settings.voxel_m) if settings.voxel_m else None  # no voxels: no grid
        jobs = [(points_m[t.halo], t.core_in_halo, settings.radius_m, settings.neighbours, settings.voxel_m, corner_m)
                for t in tiles]
        parts = self.task_map(features_of_core, jobs, [len(t.halo) for t in tiles])
        arrays = {f.name: np.zeros((len(points_m), 3) if f.name == "normal" else len(points_m)) for f in fields(Features)}
        for tile, part in zip(tiles, parts):
            for name, values in arrays.items():
                values[tile.core] = getattr(part, name)
        return Features(**arrays)

    def associate(self, cloud: PairCloud, neighbours: dict, gates: PairGates, seed: int,
                  candidates: np.ndarray) -> Correspondences:
        """associate's pairs for the candidate p's, tile by tile: each tile pairs the candidates of its core,
        at most gates.most per fibre pair in proportion to its share of the candidates."""
        tiles = self.tiles(cloud.points_m)
        is_candidate = np.zeros(len(cloud.points_m), bool)
        is_candidate[candidates] = True
        jobs = []
        for tile in tiles:
            local = np.searchsorted(tile.halo, tile.core[is_candidate[tile.core]])  # the core's candidates, sorted
            most = None if gates.most is None else max(math.ceil(gates.most * len(local) / max(len(candidates), 1)), 1)
            sight = None if cloud.sight is None else cloud.sight.take(tile.halo)
            # fibres as int16 (a head has far fewer): a tile's job carries 6 bytes a return less
            jobs.append((PairCloud(cloud.points_m[tile.halo], cloud.fibre[tile.halo].astype(np.int16),
                                   cloud.features.take(tile.halo), sight), neighbours,
                         PairGates(gates.gate_m, gates.min_planarity, gates.min_normal_cos,
                                   gates.max_plane_distance_m, most),
                         [seed, *(k & 0xFFFFFFFF for k in tile.key)], local))
        parts = self.task_map(pairs_of_core, jobs, [len(t.halo) for t in tiles])
        found = [(tile, part) for tile, part in zip(tiles, parts) if len(part)]  # a tile may pair nothing
        if not found:
            return parts[0] if parts else pairs_of_core((cloud, neighbours, gates, [seed], candidates[:0]))
        shifted = cloud.sight is not None
        return Correspondences(
            np.concatenate([t.halo[p.index_p] for t, p in found]), np.concatenate([t.halo[p.index_m] for t, p in found]),
            np.concatenate([p.normal for _, p in found]), np.concatenate([p.weight for _, p in found]),
            np.concatenate([p.shift_p_m for _, p in found]) if shifted else None,
            np.concatenate([p.shift_m_m for _, p in found]) if shifted else None,
            np.concatenate([p.out_of_plane_m for _, p in found]))


def features_of_core(job: tuple) -> Features:
    """One tile's job (a worker's): the features of its core rows from its halo's points [m]."""
    points_m, core_in_halo, radius_m, neighbours, voxel_m, corner_m = job
    return local_features(points_m, radius_m, neighbours, voxel_m, corner_m).take(core_in_halo)


def pairs_of_core(job: tuple) -> Correspondences:
    """One tile's job (a worker's): the pairs of its core's candidates, rows of its halo."""
    cloud, neighbours, gates, seed, candidates = job
    return associate(cloud, neighbours, gates, np.random.default_rng(seed), candidates)
