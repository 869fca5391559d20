"""Scene builders: triangle meshes (open3d) for ground, facades, poles, boxes, parked cars and trees.

Coordinates are in the simulator's local frame: x east, y north, z up [m], origin at the
scenario's map origin. Each builder is a validated spec with `kind` and `mesh()`; an object may
move at a constant velocity (moving clutter).
"""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
import open3d as o3d
from pydantic import BaseModel, ConfigDict, Field

Vec2 = tuple[float, float]
Vec3 = tuple[float, float, float]


class _Object(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")
    reflectivity: float = Field(0.5, gt=0, le=1, description="diffuse reflectivity, 0-1")
    velocity_m_s: Vec3 = Field((0.0, 0.0, 0.0), description="constant velocity of a moving object")

    @property
    def moving(self) -> bool:
        return any(v != 0.0 for v in self.velocity_m_s)


def _box(size: Vec3, center: Vec3, yaw_deg: float = 0.0) -> o3d.geometry.TriangleMesh:
    mesh = o3d.geometry.TriangleMesh.create_box(*size)
    mesh.translate(-np.asarray(size) / 2.0)
    mesh.rotate(o3d.geometry.get_rotation_matrix_from_xyz((0.0, 0.0, np.radians(yaw_deg))), center=(0, 0, 0))
    return mesh.translate(center)


# the chequerboard's lattice shifted by this fraction of a cell: a surface at a round coordinate (the ground at
# z = 0, a facade at y = 7.5 m) must not lie on a cell boundary, where rounding would pick the cell
LATTICE_SHIFT = 0.37


class Markings(BaseModel):
    """Painted patches on every static surface (road markings, dark windows, stains): the diffuse reflectivity of
    the cells of a chequerboard of side cell_m in the local frame (x, y, z), every other cell, is lowered by the
    fraction `contrast`. Real surfaces are not of one reflectivity, and a return's intensity then varies along
    one surface, not only from one surface to the next."""

    model_config = ConfigDict(frozen=True, extra="forbid")
    cell_m: float = Field(1.0, gt=0, description="side of the chequerboard's cells [m]")
    contrast: float = Field(0.7, ge=0, lt=1, description="fraction of the reflectivity the dark cells lose")

    def factor(self, points_local_m: np.ndarray) -> np.ndarray:
        """(N,) the reflectivity's factor at points (N, 3) [m, local frame]: 1 - contrast on dark cells, else 1."""
        cells = np.floor(np.asarray(points_local_m) / self.cell_m + LATTICE_SHIFT).astype(np.int64).sum(axis=1)
        return np.where(cells % 2 == 1, 1.0 - self.contrast, 1.0)


class Ground(_Object):
    """A flat horizontal rectangle at height z_m (two triangles)."""

    kind: Literal["ground"] = "ground"
    center_xy: Vec2 = (0.0, 0.0)
    size_m: Vec2 = (200.0, 200.0)
    z_m: float = 0.0

    def mesh(self) -> o3d.geometry.TriangleMesh:
        (cx, cy), (sx, sy) = self.center_xy, self.size_m
        corners = np.array([[cx - sx / 2, cy - sy / 2], [cx + sx / 2, cy - sy / 2],
                            [cx + sx / 2, cy + sy / 2], [cx - sx / 2, cy + sy / 2]])
        vertices = np.column_stack([corners, np.full(4, self.z_m)])
        return o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(vertices),
                                         o3d.utility.Vector3iVector(np.array([[0, 1, 2], [0, 2, 3]])))


class Facade(_Object):
    """A building front from start_xy to end_xy, with pilasters every `relief_spacing_m`
    protruding `relief_depth_m` towards the street side (left of start->end), 0 for none, and
    horizontal ledges (cornices, balcony slabs) along the whole front at `ledge_heights_m`
    (their horizontal top and underside faces are what the upward fibres see level)."""

    kind: Literal["facade"] = "facade"
    start_xy: Vec2
    end_xy: Vec2
    height_m: float = Field(12.0, gt=0)
    thickness_m: float = Field(0.5, gt=0)
    relief_spacing_m: float = Field(0.0, ge=0)
    relief_depth_m: float = Field(0.3, ge=0)
    relief_width_m: float = Field(0.6, gt=0)
    ledge_heights_m: tuple[float, ...] = Field((), description="heights of the ledges' centres [m]")
    ledge_depth_m: float = Field(0.5, gt=0)
    ledge_thickness_m: float = Field(0.2, gt=0)

    def mesh(self) -> o3d.geometry.TriangleMesh:
        start, end = np.asarray(self.start_xy), np.asarray(self.end_xy)
        length = float(np.linalg.norm(end - start))
        along = (end - start) / length
        left = np.array([-along[1], along[0]])
        yaw = float(np.degrees(np.arctan2(along[1], along[0])))
        centre = (start + end) / 2 - left * self.thickness_m / 2
        mesh = _box((length, self.thickness_m, self.height_m), (*centre, self.height_m / 2), yaw)
        if self.relief_spacing_m > 0 and self.relief_depth_m > 0:
            for s in np.arange(self.relief_spacing_m / 2, length, self.relief_spacing_m):
                xy = start + along * s + left * self.relief_depth_m / 2
                mesh += _box((self.relief_width_m, self.relief_depth_m, self.height_m), (*xy, self.height_m / 2), yaw)
        for height in self.ledge_heights_m:
            xy = (start + end) / 2 + left * self.ledge_depth_m / 2
            mesh += _box((length, self.ledge_depth_m, self.ledge_thickness_m), (*xy, height), yaw)
        return mesh


class Pole(_Object):
    """A vertical cylinder standing on the ground at xy."""

    kind: Literal["pole"] = "pole"
    xy: Vec2
    radius_m: float = Field(0.15, gt=0)
    height_m: float = Field(6.0, gt=0)

    def mesh(self) -> o3d.geometry.TriangleMesh:
        mesh = o3d.geometry.TriangleMesh.create_cylinder(self.radius_m, self.height_m, resolution=24, split=1)
        return mesh.translate((*self.xy, self.height_m / 2))


class Box(_Object):
    """An axis-aligned (then yawed) box given by its centre and size [m]."""

    kind: Literal["box"] = "box"
    center: Vec3
    size_m: Vec3
    yaw_deg: float = 0.0

    def mesh(self) -> o3d.geometry.TriangleMesh:
        return _box(self.size_m, self.center, self.yaw_deg)


class ParkedCar(_Object):
    """A car-sized body (4.5 x 1.8 x 1.0 m, 0.3 m above ground) with a cabin on top."""

    kind: Literal["car"] = "car"
    xy: Vec2
    yaw_deg: float = 0.0

    def mesh(self) -> o3d.geometry.TriangleMesh:
        yaw = np.radians(self.yaw_deg)
        forward = np.array([np.cos(yaw), np.sin(yaw)])
        body = _box((4.5, 1.8, 1.0), (*self.xy, 0.8), self.yaw_deg)
        cabin_xy = np.asarray(self.xy) - 0.3 * forward
        return body + _box((2.5, 1.6, 0.5), (*cabin_xy, 1.55), self.yaw_deg)


class Tree(_Object):
    """A street tree standing on the ground at xy: a trunk (8-sided cylinder) under a round crown (a coarse
    sphere, solid) whose centre is 0.8 crown radius above the trunk's top [m]."""

    kind: Literal["tree"] = "tree"
    xy: Vec2
    trunk_radius_m: float = Field(0.15, gt=0)
    trunk_height_m: float = Field(3.0, gt=0)
    crown_radius_m: float = Field(2.0, gt=0)
    reflectivity: float = Field(0.3, gt=0, le=1, description="diffuse reflectivity, 0-1")

    def mesh(self) -> o3d.geometry.TriangleMesh:
        trunk = o3d.geometry.TriangleMesh.create_cylinder(self.trunk_radius_m, self.trunk_height_m, resolution=8,
                                                          split=1)
        crown = o3d.geometry.TriangleMesh.create_sphere(self.crown_radius_m, resolution=6)
        crown_z = self.trunk_height_m + 0.8 * self.crown_radius_m
        return trunk.translate((*self.xy, self.trunk_height_m / 2)) + crown.translate((*self.xy, crown_z))


SceneObject = Annotated[Ground | Facade | Pole | Box | ParkedCar | Tree, Field(discriminator="kind")]


def street(length_m: float, width_m: float, height_m: float = 12.0, relief_spacing_m: float = 6.0,
           start_x_m: float = -10.0, ledge_heights_m: tuple[float, ...] = ()) -> list:
    """Ground and two facades along the x axis, `width_m` apart, centred on y = 0."""
    half = width_m / 2
    end_x = start_x_m + length_m
    return [Ground(center_xy=(start_x_m + length_m / 2, 0.0), size_m=(length_m + 40, width_m + 40)),
            Facade(start_xy=(end_x, half), end_xy=(start_x_m, half), height_m=height_m,
                   relief_spacing_m=relief_spacing_m, ledge_heights_m=ledge_heights_m),
            Facade(start_xy=(start_x_m, -half), end_xy=(end_x, -half), height_m=height_m,
                   relief_spacing_m=relief_spacing_m, ledge_heights_m=ledge_heights_m)]


class RaycastScene:
    """open3d RaycastingScene over the objects, rebuilt at a given time when some move."""

    def __init__(self, objects: list):
        self.objects = list(objects)
        self._meshes = [o3d.t.geometry.TriangleMesh.from_legacy(obj.mesh()) for obj in self.objects]
        self.moving = any(obj.moving for obj in self.objects)
        self.reflectivity = np.array([obj.reflectivity for obj in self.objects], dtype=np.float32)
        self._static = None if self.moving else self._build(0.0)

    def _build(self, elapsed_s: float) -> tuple:
        scene = o3d.t.geometry.RaycastingScene()
        ids = []
        for obj, mesh in zip(self.objects, self._meshes):
            if obj.moving:
                mesh = mesh.clone().translate(np.asarray(obj.velocity_m_s) * elapsed_s)
            ids.append(scene.add_triangles(mesh))
        return scene, np.asarray(ids)

    def cast(self, origins: np.ndarray, directions: np.ndarray, elapsed_s: float = 0.0):
        """Rays in the local frame -> (distance m, inf on a miss; object index; unit normal)."""
        scene, ids = self._static or self._build(elapsed_s)
        rays = o3d.core.Tensor(np.hstack([origins, directions]).astype(np.float32))
        hit = scene.cast_rays(rays)
        distance = hit["t_hit"].numpy().astype(np.float64)
        geometry = hit["geometry_ids"].numpy()
        lookup = np.full(max(int(ids.max()) + 2, 1), -1)
        lookup[ids] = np.arange(len(ids))
        index = np.where(np.isfinite(distance), lookup[np.minimum(geometry, len(lookup) - 1)], -1)
        return distance, index, hit["primitive_normals"].numpy().astype(np.float64)
