"""A procedural city district: blocks of buildings on a grid of streets, sidewalks, crossings with bollards,
street lights, parked cars, trees and street clutter, every choice drawn from a seeded generator.

Local frame x east, y north, z up [m]. The streets run along the lines of a grid of n_x x n_y blocks, crossing
(i, j) at (i pitch, j pitch) with pitch = block_m + street_m (route.py drives them); street_m is the width between
facades, sidewalk_m of it on each side a 0.15 m high kerb. Each block side is a row of buildings (facades of
their own height, pilasters and ledges); a ring of buildings faces the outer streets. Nothing here moves (a moving
object makes the simulator rebuild its raycasting scene every 10 ms): traffic on these streets is
traffic.DistrictTrafficSpec's boxes, cast ray by ray.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from graphcal.simulation.scene import Box, Facade, Ground, ParkedCar, Pole, SceneObject, Tree

KERB_M = 0.15  # sidewalk height [m]
_STOREY_M = 3.2  # ledge spacing on a facade [m]
_CAR_SLOT_M = 6.0  # length of a parking space [m]


@dataclass(frozen=True)
class DistrictLayout:
    """The district's grid: n_x x n_y blocks of block_m, streets street_m wide between facades, sidewalks
    sidewalk_m wide on each side [m]."""

    n_x: int = 2
    n_y: int = 2
    block_m: float = 40.0
    street_m: float = 16.0
    sidewalk_m: float = 3.0

    @property
    def pitch_m(self) -> float:
        """Distance between neighbouring crossings [m]."""
        return self.block_m + self.street_m

    @property
    def road_half_m(self) -> float:
        """Distance from a street's centre line to its kerbs [m]."""
        return self.street_m / 2 - self.sidewalk_m


def district(layout: DistrictLayout, rng: np.random.Generator) -> list[SceneObject]:
    """The scene objects of the district: ground, kerbs, buildings, crossings and street furniture."""
    pitch, half = layout.pitch_m, layout.street_m / 2
    outer = (-half, -half, layout.n_x * pitch + half, layout.n_y * pitch + half)
    objects: list[SceneObject] = [Ground(center_xy=((outer[0] + outer[2]) / 2, (outer[1] + outer[3]) / 2),
                                         size_m=(outer[2] - outer[0] + 60.0, outer[3] - outer[1] + 60.0))]
    for i in range(layout.n_x):
        for j in range(layout.n_y):
            x0, y0 = i * pitch + half, j * pitch + half
            x1, y1 = x0 + layout.block_m, y0 + layout.block_m
            objects.append(Box(center=((x0 + x1) / 2, (y0 + y1) / 2, KERB_M / 2),
                               size_m=(layout.block_m + 2 * layout.sidewalk_m,) * 2 + (KERB_M,)))
            # clockwise: the street (each facade's front, left of start -> end) is outside the block
            objects += _buildings([(x0, y0), (x0, y1), (x1, y1), (x1, y0)], rng)
    x0, y0, x1, y1 = outer
    objects += _outer_sidewalks(outer, layout.sidewalk_m)
    objects += _buildings([(x0, y0), (x1, y0), (x1, y1), (x0, y1)], rng)  # counter-clockwise: facing inwards
    for i in range(layout.n_x + 1):
        for j in range(layout.n_y + 1):
            objects += _bollards((i * pitch, j * pitch), layout.road_half_m + 0.3)
            if i < layout.n_x:
                objects += _furniture((i * pitch, j * pitch), (1.0, 0.0), layout, rng)
            if j < layout.n_y:
                objects += _furniture((i * pitch, j * pitch), (0.0, 1.0), layout, rng)
    return objects


def _buildings(corners: list[tuple[float, float]], rng: np.random.Generator) -> list[Facade]:
    """Rows of buildings along the closed polygon's sides, each side cut into 2-4 fronts of random height
    (6-22 m), pilaster spacing, ledges and reflectivity."""
    facades = []
    for start, end in zip(corners, corners[1:] + corners[:1]):
        start, end = np.asarray(start), np.asarray(end)
        cuts = np.sort(rng.uniform(0.15, 0.85, rng.integers(1, 4)))
        for a, b in zip(np.r_[0.0, cuts], np.r_[cuts, 1.0]):
            height_m = float(rng.uniform(6.0, 22.0))
            relief_spacing_m = float(rng.choice([0.0, 3.0, 4.0, 5.0, 6.0]))
            relief_depth_m = float(rng.uniform(0.15, 0.45))
            storeys = np.arange(_STOREY_M, height_m - 1.0, _STOREY_M)
            ledges_m = tuple(float(h) for h in storeys[rng.uniform(size=len(storeys)) < 0.4])
            facades.append(Facade(start_xy=tuple(start + a * (end - start)), end_xy=tuple(start + b * (end - start)),
                                  height_m=height_m, relief_spacing_m=relief_spacing_m, relief_depth_m=relief_depth_m,
                                  ledge_heights_m=ledges_m,
                                  reflectivity=float(rng.uniform(0.3, 0.8))))
    return facades


def _outer_sidewalks(outer: tuple[float, float, float, float], sidewalk_m: float) -> list[Box]:
    """The kerbed sidewalks in front of the outer ring of buildings."""
    x0, y0, x1, y1 = outer
    cx, cy, sx, sy = (x0 + x1) / 2, (y0 + y1) / 2, x1 - x0, y1 - y0
    z = KERB_M / 2
    return [Box(center=(cx, y0 + sidewalk_m / 2, z), size_m=(sx, sidewalk_m, KERB_M)),
            Box(center=(cx, y1 - sidewalk_m / 2, z), size_m=(sx, sidewalk_m, KERB_M)),
            Box(center=(x0 + sidewalk_m / 2, cy, z), size_m=(sidewalk_m, sy, KERB_M)),
            Box(center=(x1 - sidewalk_m / 2, cy, z), size_m=(sidewalk_m, sy, KERB_M))]


def _bollards(crossing_xy: tuple[float, float], offset_m: float) -> list[Pole]:
    """A bollard (1 m, 10 cm radius) at each kerb corner of a crossing."""
    x, y = crossing_xy
    return [Pole(xy=(x + sx * offset_m, y + sy * offset_m), radius_m=0.1, height_m=1.0, reflectivity=0.6)
            for sx in (-1, 1) for sy in (-1, 1)]


def _furniture(from_xy: tuple[float, float], along: tuple[float, float], layout: DistrictLayout,
               rng: np.random.Generator) -> list[SceneObject]:
    """Street lights, parked cars, trees and clutter on both sides of the street from crossing from_xy
    towards its neighbour along `along` (a unit axis), clear of the crossings."""
    origin, along = np.asarray(from_xy), np.asarray(along)
    left = np.array([-along[1], along[0]])
    yaw_deg = float(np.degrees(np.arctan2(along[1], along[0])))
    first_m, last_m = layout.street_m / 2 + 3.0, layout.pitch_m - layout.street_m / 2 - 3.0
    kerb_m = layout.road_half_m

    def at(s: float, lateral: float) -> tuple[float, float]:
        return tuple(float(c) for c in origin + s * along + lateral * left)

    objects: list[SceneObject] = []
    for side in (-1.0, 1.0):
        for s in np.arange(first_m + rng.uniform(0.0, 6.0), last_m, 18.0):
            objects.append(Pole(xy=at(s, side * (kerb_m + 0.5)), height_m=float(rng.uniform(5.0, 8.0))))
        if rng.uniform() < 0.6:
            for s in np.arange(first_m + _CAR_SLOT_M / 2, last_m - _CAR_SLOT_M / 2, _CAR_SLOT_M):
                if rng.uniform() < 0.6:
                    objects.append(ParkedCar(xy=at(s + rng.uniform(-0.5, 0.5), side * (kerb_m - 1.1)),
                                             yaw_deg=yaw_deg + float(rng.normal(0.0, 2.0)),
                                             reflectivity=float(rng.uniform(0.2, 0.9))))
        if rng.uniform() < 0.5:
            for s in np.arange(first_m + rng.uniform(2.0, 6.0), last_m, 9.0):
                objects.append(Tree(xy=at(s, side * (kerb_m + 1.6)), crown_radius_m=float(rng.uniform(1.5, 2.5))))
        for _ in range(rng.integers(0, 3)):
            size = tuple(float(v) for v in rng.uniform((0.5, 0.5, 0.8), (1.6, 1.6, 2.2)))
            xy = at(rng.uniform(first_m, last_m), side * (kerb_m + 0.4 + size[1] / 2))
            objects.append(Box(center=(*xy, KERB_M + size[2] / 2), size_m=size, yaw_deg=yaw_deg,
                               reflectivity=float(rng.uniform(0.2, 0.8))))
    return objects
