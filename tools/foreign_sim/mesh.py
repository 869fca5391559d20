"""Triangle-mesh building blocks, written from scratch with numpy.

Everything is in the layout frame (x, y horizontal, z up, metres). A `MeshBuilder` collects
triangles with a per-triangle reflectivity (0-1, diffuse) and a material id; `finish()` returns
plain arrays. A `Frame` places objects along a road: u along the road, v away from it, z up.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

# material ids (what a surface is made of: decides texture, detection and intensity behaviour)
GROUND = 0       # textured ground: asphalt, lane paint, pavement, grass ... (see scenes.GroundTexture)
PAVEMENT = 1
GRASS = 2
FACADE = 3
GLASS = 4        # windows: specular, few returns
CAR = 5
VEGETATION = 6
METAL = 7
RAIL = 8         # galvanised guard rail
SIGN = 9         # retro-reflective sign sheeting
ROOF = 10
WOOD = 11
CONCRETE = 12
MATERIAL_NAMES = {GROUND: "ground", PAVEMENT: "pavement", GRASS: "grass", FACADE: "facade", GLASS: "glass",
                  CAR: "car", VEGETATION: "vegetation", METAL: "metal", RAIL: "rail", SIGN: "sign",
                  ROOF: "roof", WOOD: "wood", CONCRETE: "concrete"}


@dataclass(frozen=True)
class Mesh:
    vertices: np.ndarray      # (n, 3) float64, layout frame [m]
    triangles: np.ndarray     # (m, 3) int64
    reflectivity: np.ndarray  # (m,) float64, 0-1
    material: np.ndarray      # (m,) int8

    def normals(self) -> np.ndarray:
        """(m, 3) unit normals (orientation arbitrary: incidence uses |n . d|)."""
        a, b, c = (self.vertices[self.triangles[:, k]] for k in range(3))
        n = np.cross(b - a, c - a)
        return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


@dataclass(frozen=True)
class Frame:
    """A local frame on the ground: origin (x, y), unit u (along), unit v (outward); z absolute."""

    origin: np.ndarray
    u: np.ndarray
    v: np.ndarray

    @classmethod
    def at(cls, origin_xy, tangent_xy, side: float) -> Frame:
        """Frame on a road point: u = tangent, v = the side's normal (side +1 left, -1 right)."""
        t = np.asarray(tangent_xy, dtype=np.float64)
        t = t / np.linalg.norm(t)
        left = np.array([-t[1], t[0]])
        return cls(np.asarray(origin_xy, dtype=np.float64), t, side * left)

    def pt(self, u, v, z) -> np.ndarray:
        u, v, z = np.broadcast_arrays(np.asarray(u, float), np.asarray(v, float), np.asarray(z, float))
        xy = self.origin + u[..., None] * self.u + v[..., None] * self.v
        return np.concatenate([xy, z[..., None]], axis=-1)


_HEX_FACES = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7],
                       [0, 1, 5], [0, 5, 4], [1, 2, 6], [1, 6, 5],
                       [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7]])


class MeshBuilder:
    def __init__(self) -> None:
        self._v: list[np.ndarray] = []
        self._f: list[np.ndarray] = []
        self._r: list[np.ndarray] = []
        self._m: list[np.ndarray] = []
        self._n = 0

    def add(self, vertices, faces, reflectivity, material) -> None:
        v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
        f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
        self._v.append(v)
        self._f.append(f + self._n)
        self._r.append(np.broadcast_to(np.asarray(reflectivity, dtype=np.float64), (len(f),)).copy())
        self._m.append(np.broadcast_to(np.asarray(material, dtype=np.int8), (len(f),)).copy())
        self._n += len(v)

    # --- solids -----------------------------------------------------------------------------
    def hexahedron(self, corners, reflectivity, material) -> None:
        """8 corners: bottom 4 in order around, then the top 4 in the same order."""
        self.add(corners, _HEX_FACES, reflectivity, material)

    def box(self, frame: Frame, u0, u1, v0, v1, z0, z1, reflectivity, material) -> None:
        """A box aligned with the frame: u in [u0, u1], v in [v0, v1], z in [z0, z1]."""
        u = [u0, u1, u1, u0]
        v = [v0, v0, v1, v1]
        bottom = frame.pt(u, v, [z0] * 4)
        top = frame.pt(u, v, [z1] * 4)
        self.hexahedron(np.vstack([bottom, top]), reflectivity, material)

    def axis_box(self, x0, x1, y0, y1, z0, z1, reflectivity, material) -> None:
        frame = Frame(np.zeros(2), np.array([1.0, 0.0]), np.array([0.0, 1.0]))
        self.box(frame, x0, x1, y0, y1, z0, z1, reflectivity, material)

    def prism(self, frame: Frame, polygon_vz, u0, u1, reflectivity, material) -> None:
        """A convex polygon in the (v, z) plane extruded along u from u0 to u1."""
        poly = np.asarray(polygon_vz, dtype=np.float64)
        k = len(poly)
        a = frame.pt(np.full(k, u0), poly[:, 0], poly[:, 1])
        b = frame.pt(np.full(k, u1), poly[:, 0], poly[:, 1])
        faces = [[0, i + 1, i] for i in range(1, k - 1)] + [[k, k + i, k + i + 1] for i in range(1, k - 1)]
        for i in range(k):
            j = (i + 1) % k
            faces += [[i, j, k + j], [i, k + j, k + i]]
        self.add(np.vstack([a, b]), faces, reflectivity, material)

    def quad(self, p0, p1, p2, p3, reflectivity, material) -> None:
        self.add(np.array([p0, p1, p2, p3]), [[0, 1, 2], [0, 2, 3]], reflectivity, material)

    def cylinder(self, base, axis, radius, length, reflectivity, material, sides: int = 10) -> None:
        """A closed cylinder from `base` along the unit `axis`."""
        base = np.asarray(base, dtype=np.float64)
        axis = np.asarray(axis, dtype=np.float64)
        axis = axis / np.linalg.norm(axis)
        helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        e1 = np.cross(axis, helper)
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(axis, e1)
        phi = np.linspace(0.0, 2 * np.pi, sides, endpoint=False)
        ring = radius * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2)
        vertices = np.vstack([base + ring, base + length * axis + ring, base, base + length * axis])
        n = sides
        faces = []
        for i in range(n):
            j = (i + 1) % n
            faces += [[i, j, n + j], [i, n + j, n + i], [2 * n, j, i], [2 * n + 1, n + i, n + j]]
        self.add(vertices, faces, reflectivity, material)

    def ellipsoid(self, center, radii, reflectivity, material, rng=None, bumpiness: float = 0.0,
                  subdivisions: int = 2) -> None:
        """An ellipsoid from a subdivided icosahedron; bumpiness > 0 perturbs each vertex radially."""
        vertices, faces = unit_icosphere(subdivisions)
        scale = np.ones(len(vertices))
        if bumpiness > 0 and rng is not None:
            scale = 1.0 + bumpiness * rng.uniform(-1.0, 1.0, len(vertices))
        points = np.asarray(center) + vertices * scale[:, None] * np.asarray(radii)
        self.add(points, faces, reflectivity, material)

    def ribbon(self, bottom, top, reflectivity, material) -> None:
        """A strip between two polylines of equal length (k, 3)."""
        bottom, top = np.asarray(bottom, float), np.asarray(top, float)
        k = len(bottom)
        i = np.arange(k - 1)
        faces = np.concatenate([np.stack([i, i + 1, k + i + 1], 1), np.stack([i, k + i + 1, k + i], 1)])
        self.add(np.vstack([bottom, top]), faces, reflectivity, material)

    def height_field(self, x, y, z, keep, reflectivity, material) -> None:
        """A grid surface: x (nx,), y (ny,), z (ny, nx); keep (ny-1, nx-1) selects cells."""
        nx = len(x)
        X, Y = np.meshgrid(x, y)
        vertices = np.column_stack([X.ravel(), Y.ravel(), np.asarray(z).ravel()])
        jj, ii = np.nonzero(keep)
        a = jj * nx + ii
        b, c, d = a + 1, a + nx + 1, a + nx
        faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
        used = np.unique(faces)
        remap = np.full(len(vertices), -1, dtype=np.int64)
        remap[used] = np.arange(len(used))
        self.add(vertices[used], remap[faces], reflectivity, material)

    def finish(self) -> Mesh:
        return Mesh(np.vstack(self._v), np.vstack(self._f), np.concatenate(self._r), np.concatenate(self._m))


@lru_cache(maxsize=4)
def unit_icosphere(subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    """Vertices on the unit sphere and faces of an icosahedron subdivided `subdivisions` times."""
    g = (1.0 + 5 ** 0.5) / 2.0
    v = [[-1, g, 0], [1, g, 0], [-1, -g, 0], [1, -g, 0], [0, -1, g], [0, 1, g], [0, -1, -g], [0, 1, -g],
         [g, 0, -1], [g, 0, 1], [-g, 0, -1], [-g, 0, 1]]
    f = [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2],
         [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5],
         [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]]
    vertices = [np.array(p, dtype=np.float64) / np.linalg.norm(p) for p in v]
    faces = f
    for _ in range(subdivisions):
        cache: dict[tuple[int, int], int] = {}

        def midpoint(i, j):
            key = (min(i, j), max(i, j))
            if key not in cache:
                m = vertices[i] + vertices[j]
                vertices.append(m / np.linalg.norm(m))
                cache[key] = len(vertices) - 1
            return cache[key]

        new = []
        for a, b, c in faces:
            ab, bc, ca = midpoint(a, b), midpoint(b, c), midpoint(c, a)
            new += [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
        faces = new
    return np.array(vertices), np.array(faces, dtype=np.int64)
