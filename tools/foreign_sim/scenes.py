"""Scene families: the road layout, the drive along it and the triangle meshes around it.

Each family builds, from one random generator, a `World`: the path and speed programme of the
drive, the roads (for the ground texture), the ground height function the car rests on, and the
mesh. All in the layout frame (x, y horizontal, z up, m); the drive starts at (0, 0) heading +x.

- box_street: box facades (8-20 m) 7.5-10 m from the centre line, no relief, flat ground,
  parked cars, lamp posts; T-junction, the drive turns left.
- suburb: gable-roofed detached houses behind front gardens, hedges and fences, trees (bumpy
  ellipsoid crowns), a curving cambered road on a grade; the drive turns left into a side street.
- open_road: a rural road with long straights and a bend, ditch and embankment beside it, guard
  rail, delineators, sign posts, a few trees, a far warehouse and a farmhouse.
- relief_street: a city street whose buildings have recessed windows, balconies, cornices,
  pilasters and shop fronts, varying heights and set-backs, kerbs and raised pavements; a
  four-way crossing where the drive turns left.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy.spatial import cKDTree

from tools.foreign_sim import mesh as M
from tools.foreign_sim.drive import Path, SpeedProgramme, path_from_plan
from tools.foreign_sim.mesh import Frame, MeshBuilder

LANE_OFFSET_M = 1.75   # the car drives 1.75 m right of its road's centre line
REACH_M = 112.0        # scene objects are built within this distance of the driven path


# --- roads and ground texture ------------------------------------------------------------------
def _densify(polyline, step: float = 0.25) -> np.ndarray:
    p = np.asarray(polyline, dtype=np.float64)
    seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
    keep = np.concatenate([[True], seg > 1e-9])
    p = p[keep]
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    t = np.linspace(0.0, s[-1], max(int(np.ceil(s[-1] / step)), 1) + 1)
    return np.column_stack([np.interp(t, s, p[:, 0]), np.interp(t, s, p[:, 1])])


class Road:
    """A road centre line (dense polyline), its half width and its markings."""

    def __init__(self, polyline, half_width: float, centre: str = "dashed", edges: bool = False,
                 asphalt: float = 0.15):
        self.xy = _densify(polyline)
        self.half_width, self.centre, self.edges, self.asphalt = half_width, centre, edges, asphalt
        d = np.diff(self.xy, axis=0)
        ds = np.linalg.norm(d, axis=1)
        self.s = np.concatenate([[0.0], np.cumsum(ds)])
        t = np.vstack([d, d[-1:]]) / np.concatenate([ds, ds[-1:]])[:, None]
        self.t = t
        self.n = np.column_stack([-t[:, 1], t[:, 0]])  # left normal
        self.tree = cKDTree(self.xy)

    @property
    def length(self) -> float:
        return float(self.s[-1])

    def point(self, s):
        """(xy, unit tangent) at arc length s (clipped to the road)."""
        s = float(np.clip(s, 0.0, self.length))
        i = int(np.clip(np.searchsorted(self.s, s) - 1, 0, len(self.s) - 2))
        a = (s - self.s[i]) / max(self.s[i + 1] - self.s[i], 1e-12)
        return (1 - a) * self.xy[i] + a * self.xy[i + 1], self.t[i]

    def project(self, p) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(s, signed lateral (left +), distance to the centre line) of points (N, 2)."""
        p = np.asarray(p, dtype=np.float64)[:, :2]
        _, i = self.tree.query(p)
        d = p - self.xy[i]
        s = self.s[i] + np.einsum("ij,ij->i", d, self.t[i])
        lat = np.einsum("ij,ij->i", d, self.n[i])
        beyond = np.maximum(-s, 0.0) + np.maximum(s - self.length, 0.0)
        return s, lat, np.hypot(lat, beyond)

    def distance(self, p) -> np.ndarray:
        return self.project(p)[2]


def _hash01(ix, iy, salt: int) -> np.ndarray:
    """Deterministic uniform [0, 1) per integer cell (a small integer hash)."""
    h = (np.asarray(ix, dtype=np.int64).astype(np.uint64) * np.uint64(0x9E3779B1)
         ^ np.asarray(iy, dtype=np.int64).astype(np.uint64) * np.uint64(0x85EBCA77)
         ^ np.uint64(salt * 0xC2B2AE3D & 0xFFFFFFFF))
    h ^= h >> np.uint64(15)
    h *= np.uint64(0x2C1B3C6D)
    h ^= h >> np.uint64(12)
    h *= np.uint64(0x297A2D39)
    h ^= h >> np.uint64(15)
    return (h & np.uint64(0xFFFFFF)).astype(np.float64) / float(0x1000000)


def grain(xy, cell: float, salt: int) -> np.ndarray:
    """Cell-wise noise in [-1, 1] (texture of asphalt, grass, concrete)."""
    xy = np.asarray(xy)
    return 2.0 * _hash01(np.floor(xy[:, 0] / cell), np.floor(xy[:, 1] / cell), salt) - 1.0


class GroundTexture:
    """Reflectivity of the GROUND material at hit points: asphalt with lane paint on the roads,
    the family's off-road surface elsewhere."""

    def __init__(self, roads: list[Road], offroad: Callable[[np.ndarray], np.ndarray], salt: int):
        self.roads, self.offroad, self.salt = roads, offroad, salt

    def __call__(self, p: np.ndarray) -> np.ndarray:
        p = np.asarray(p)
        refl = self.offroad(p)
        on_count = np.zeros(len(p), dtype=np.int64)
        paint = np.zeros(len(p), dtype=bool)
        for k, road in enumerate(self.roads):
            s, lat, dist = road.project(p)
            on = (dist <= road.half_width) & (s >= 0) & (s <= road.length)
            on_count += on
            asphalt = road.asphalt * (1.0 + 0.25 * grain(p, 0.08, self.salt + k)
                                      + 0.15 * grain(p, 1.7, self.salt + 7 * k + 3))
            refl = np.where(on, asphalt, refl)
            marks = np.zeros(len(p), dtype=bool)
            if road.centre == "dashed":
                marks |= (np.abs(lat) < 0.06) & (np.mod(s, 9.0) < 3.0)
            elif road.centre == "solid":
                marks |= np.abs(lat) < 0.06
            if road.edges:
                marks |= np.abs(np.abs(lat) - (road.half_width - 0.25)) < 0.075
            paint |= on & marks
        paint &= on_count == 1
        return np.where(paint, 0.6 + 0.05 * grain(p, 0.05, self.salt + 99), np.clip(refl, 0.02, 1.0))


# --- world ------------------------------------------------------------------------------------
@dataclass
class World:
    family: str
    path: Path
    speed: SpeedProgramme
    roads: list[Road]
    mesh: M.Mesh
    ground_z: Callable[[np.ndarray], np.ndarray]
    texture: GroundTexture
    notes: dict = field(default_factory=dict)


class Site:
    """What placement needs: the driven part of the path, the roads, and checks."""

    def __init__(self, path: Path, s_lo: float, s_hi: float, roads: list[Road]):
        s = np.arange(s_lo - 5.0, s_hi + 5.0, 0.5)
        x, y, _ = path.at(s)
        self.driven = cKDTree(np.column_stack([x, y]))
        self.roads = roads
        self.bbox = (x.min() - REACH_M, x.max() + REACH_M, y.min() - REACH_M, y.max() + REACH_M)

    def near(self, xy, reach: float = REACH_M) -> np.ndarray:
        return self.driven.query(np.atleast_2d(xy)[:, :2])[0] <= reach

    def off_path(self, xy, clearance: float) -> bool:
        """True if every point is at least `clearance` from the car's route."""
        return bool(np.all(self.driven.query(np.atleast_2d(xy)[:, :2])[0] >= clearance))

    def off_roads(self, xy, margin: float, skip: Road | None = None) -> bool:
        """True if every point is at least half width + margin from every road but `skip`."""
        xy = np.atleast_2d(xy)[:, :2]
        return all(np.all(r.distance(xy) >= r.half_width + margin) for r in self.roads if r is not skip)


def footprint(frame: Frame, u0, u1, v0, v1) -> np.ndarray:
    """Corners and edge mid-points of a rectangle of a frame, (8, 2)."""
    u = [u0, u1, u1, u0, (u0 + u1) / 2, u1, (u0 + u1) / 2, u0]
    v = [v0, v0, v1, v1, v0, (v0 + v1) / 2, v1, (v0 + v1) / 2]
    return frame.pt(u, v, 0.0)[:, :2]


def frame_on(road: Road, s: float, side: float) -> Frame:
    xy, t = road.point(s)
    return Frame.at(xy, t, side)


def junction(path: Path, s_before: float, s_after: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where the centre lines of the road before and after a turn cross: (J, dir before, dir after)."""
    x0, y0, h0 = path.at(s_before)
    x1, y1, h1 = path.at(s_after)
    d0 = np.array([np.cos(h0), np.sin(h0)])
    d1 = np.array([np.cos(h1), np.sin(h1)])
    p0 = np.array([x0, y0]) + LANE_OFFSET_M * np.array([-d0[1], d0[0]])
    p1 = np.array([x1, y1]) + LANE_OFFSET_M * np.array([-d1[1], d1[0]])
    a, _ = np.linalg.solve(np.column_stack([d0, -d1]), p1 - p0)
    return p0 + a * d0, d0, d1


# --- objects ------------------------------------------------------------------------------------
def car(mb: MeshBuilder, frame: Frame, u_c: float, v_c: float, z0: float, rng) -> None:
    """A parked car, length along the frame's u: body, tapered cabin, four wheels."""
    length, width = rng.uniform(3.9, 4.8), rng.uniform(1.68, 1.86)
    refl = rng.uniform(0.2, 0.8)
    body_top = z0 + rng.uniform(0.95, 1.05)
    mb.box(frame, u_c - length / 2, u_c + length / 2, v_c - width / 2, v_c + width / 2, z0 + 0.3, body_top,
           refl, M.CAR)
    roof = z0 + rng.uniform(1.40, 1.55)
    b0, b1 = u_c - 0.36 * length, u_c + 0.18 * length
    t0, t1 = u_c - 0.27 * length, u_c + 0.02 * length
    wb, wt = width / 2 - 0.05, width / 2 - 0.2
    bottom = frame.pt([b0, b1, b1, b0], [v_c - wb, v_c - wb, v_c + wb, v_c + wb], [body_top] * 4)
    top = frame.pt([t0, t1, t1, t0], [v_c - wt, v_c - wt, v_c + wt, v_c + wt], [roof] * 4)
    mb.hexahedron(np.vstack([bottom, top]), 0.7 * refl, M.CAR)
    axis = np.append(frame.v, 0.0)
    for du in (-1, 1):
        for dv in (-1, 1):
            base = frame.pt(u_c + du * (length / 2 - 0.8), v_c + dv * (width / 2) - (0.22 if dv > 0 else 0.0),
                            z0 + 0.32)
            mb.cylinder(base, axis, 0.32, 0.22, 0.05, M.CAR, sides=8)


def lamp_post(mb: MeshBuilder, frame: Frame, v: float, z0: float, rng) -> None:
    """A lamp post at lateral v with an arm reaching over the road (towards smaller v)."""
    h = rng.uniform(6.0, 8.0)
    r = rng.uniform(0.07, 0.12)
    refl = rng.uniform(0.35, 0.6)
    mb.cylinder(frame.pt(0.0, v, z0 - 0.2), [0, 0, 1], r, h + 0.2, refl, M.METAL)
    mb.box(frame, -0.04, 0.04, v - 1.5, v, z0 + h - 0.12, z0 + h, refl, M.METAL)
    mb.box(frame, -0.18, 0.18, v - 1.75, v - 1.2, z0 + h - 0.28, z0 + h - 0.08, 0.5, M.METAL)


def bollard(mb: MeshBuilder, xy, z0: float) -> None:
    mb.cylinder([xy[0], xy[1], z0 - 0.1], [0, 0, 1], 0.09, 1.0, 0.5, M.METAL, sides=8)


def tree(mb: MeshBuilder, xy, z0: float, rng, scale: float = 1.0) -> None:
    trunk_h = rng.uniform(1.8, 3.0) * scale
    r_crown = rng.uniform(1.5, 3.0) * scale
    rz = rng.uniform(1.8, 3.5) * scale
    mb.cylinder([xy[0], xy[1], z0 - 0.2], [0, 0, 1], rng.uniform(0.12, 0.25) * scale, trunk_h + 0.2 + rz * 0.5,
                rng.uniform(0.25, 0.35), M.WOOD, sides=8)
    squash = rng.uniform(0.85, 1.15)
    mb.ellipsoid([xy[0] + rng.normal(0, 0.2), xy[1] + rng.normal(0, 0.2), z0 + trunk_h + 0.8 * rz],
                 [r_crown * squash, r_crown / squash, rz], rng.uniform(0.35, 0.45), M.VEGETATION,
                 rng=rng, bumpiness=0.14, subdivisions=2)


def gable_house(mb: MeshBuilder, frame: Frame, u0, u1, v0, v1, zb, rng, eave=None, ridge=None,
                along: bool | None = None, wall_refl=None, roof_refl=None, roof_mat=M.ROOF,
                overhang: float = 0.4) -> None:
    """A house with a gable roof on the rectangle (u0..u1, v0..v1) of a frame, base height zb."""
    eave = zb + (rng.uniform(2.8, 4.5) if eave is None else eave)
    ridge = zb + (rng.uniform(5.0, 8.0) if ridge is None else ridge)
    ridge = max(ridge, eave + 1.0)
    along = bool(rng.random() < 0.5) if along is None else along
    wall_refl = rng.uniform(0.35, 0.6) if wall_refl is None else wall_refl
    roof_refl = rng.uniform(0.15, 0.35) if roof_refl is None else roof_refl
    f = frame if along else Frame(frame.origin, frame.v, frame.u)
    if not along:
        u0, u1, v0, v1 = v0, v1, u0, u1
    vm = (v0 + v1) / 2
    mb.prism(f, [(v0, zb - 0.6), (v1, zb - 0.6), (v1, eave), (vm, ridge), (v0, eave)], u0, u1, wall_refl, M.FACADE)
    slope = (ridge - eave) / (vm - v0)
    lift = 0.08
    for edge, sign in ((v0, -1.0), (v1, 1.0)):
        e = edge + sign * overhang
        z_e = eave - overhang * slope + lift
        mb.quad(f.pt(u0 - overhang, e, z_e), f.pt(u1 + overhang, e, z_e),
                f.pt(u1 + overhang, vm, ridge + lift), f.pt(u0 - overhang, vm, ridge + lift), roof_refl, roof_mat)
    if rng.random() < 0.35:  # chimney
        cu = rng.uniform(u0 + 1.0, u1 - 1.0)
        cv = rng.uniform(v0 + 1.0, vm - 0.6)
        z_roof = eave + (cv - v0) * slope
        mb.box(f, cu - 0.3, cu + 0.3, cv - 0.3, cv + 0.3, z_roof - 0.5, ridge + 0.8, wall_refl, M.FACADE)


def flat_ground(mb: MeshBuilder, bbox, z: float = 0.0) -> None:
    x0, x1, y0, y1 = bbox
    mb.quad([x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z], 0.15, M.GROUND)


def height_field_ground(mb: MeshBuilder, site: Site, ground_z, cell: float = 1.0) -> int:
    x0, x1, y0, y1 = site.bbox
    x = np.arange(np.floor(x0), np.ceil(x1) + cell, cell)
    y = np.arange(np.floor(y0), np.ceil(y1) + cell, cell)
    X, Y = np.meshgrid(x, y)
    z = ground_z(np.column_stack([X.ravel(), Y.ravel()])).reshape(X.shape)
    cx, cy = np.meshgrid((x[:-1] + x[1:]) / 2, (y[:-1] + y[1:]) / 2)
    keep = site.near(np.column_stack([cx.ravel(), cy.ravel()]), REACH_M + 5.0).reshape(cx.shape)
    mb.height_field(x, y, z, keep, 0.15, M.GROUND)
    return int(keep.sum()) * 2


def _drive_span(speed: SpeedProgramme, duration_s: float) -> tuple[float, float]:
    s, _, _ = speed.evaluate(np.array([-0.5, duration_s + 0.5]))
    return float(s[0]), float(s[1])


# --- family: box street ----------------------------------------------------------------------------
def box_street(rng, duration_s: float) -> World:
    speed = SpeedProgramme(6.0, ((2.0, 6.0), (2.5, 9.0), (1.5, 9.0), (2.5, 4.0), (4.0, 4.0), (2.0, 8.0)))
    speed = speed.extended(duration_s, rng)
    s_turn = float(speed.evaluate(np.array([8.7]))[0][0])
    radius = float(rng.uniform(7.5, 8.5))
    s_lo, s_hi = _drive_span(speed, duration_s)
    path, turns = path_from_plan([("straight", s_turn), ("turn", 90.0, radius, 3.0)],
                                 s_lo - REACH_M - 20, s_hi + REACH_M + 20)
    (t0, t1), = turns
    J, dA, dB = junction(path, t0, t1)
    hw = 5.5
    far = REACH_M + 30
    a_start = path.offset(s_lo - REACH_M - 15, t0, LANE_OFFSET_M)
    road_a = Road(np.vstack([a_start, J]), hw, centre="dashed", edges=False, asphalt=rng.uniform(0.1, 0.2))
    b_end = max(s_hi + REACH_M + 15, t1 + 1.0)
    road_b = Road(np.vstack([J - far * dB, path.offset(t1, b_end, LANE_OFFSET_M)]), hw,
                  centre="dashed", asphalt=rng.uniform(0.1, 0.2))
    roads = [road_a, road_b]
    site = Site(path, s_lo, s_hi, roads)
    mb = MeshBuilder()
    flat_ground(mb, site.bbox)
    n_buildings = n_cars = n_poles = 0
    for road in roads:
        for side in (1.0, -1.0):
            s = rng.uniform(-5.0, 5.0)
            while s < road.length:
                w = rng.uniform(8.0, 25.0)
                gap = rng.choice([0.0, 0.0, 0.0, rng.uniform(1.0, 4.0)])
                frame = frame_on(road, s + w / 2, side)
                setback, depth, h = rng.uniform(7.5, 10.0), rng.uniform(10.0, 15.0), rng.uniform(8.0, 20.0)
                fp = footprint(frame, -w / 2, w / 2, setback, setback + depth)
                if site.near(frame.origin).all() and site.off_roads(fp, 2.0, skip=road) and site.off_path(fp, 4.0):
                    mb.box(frame, -w / 2, w / 2, setback, setback + depth, -0.5, h, rng.uniform(0.3, 0.6), M.FACADE)
                    n_buildings += 1
                s += w + gap
            s = rng.uniform(0.0, 8.0)
            while s < road.length:  # parked cars in the parking lane
                length = 5.0 + rng.uniform(0.5, 3.0)
                if rng.random() < 0.6:
                    frame = frame_on(road, s, side)
                    fp = footprint(frame, -2.5, 2.5, 4.4 - 1.0, 4.4 + 1.0)
                    if site.near(frame.origin, 90.0).all() and site.off_roads(fp, 1.0, skip=road) \
                            and site.off_path(fp, 1.4):
                        car(mb, frame, 0.0, 4.4, 0.0, rng)
                        n_cars += 1
                s += length
            s = rng.uniform(0.0, 25.0)
            while s < road.length:  # lamp posts on the pavement
                frame = frame_on(road, s, side)
                if site.near(frame.origin).all() and site.off_roads(frame.pt(0, 6.2, 0)[None, :2], 0.5, skip=road) \
                        and site.off_path(frame.pt(0, 6.2, 0)[None, :2], 2.0):
                    lamp_post(mb, frame, 6.2, 0.0, rng)
                    n_poles += 1
                s += rng.uniform(22.0, 32.0)
    for corner in ((-1, 1), (-1, -1), (1, 1), (1, -1)):  # bollards at the junction corners
        xy = J + corner[0] * (hw + 0.6) * dA + corner[1] * (hw + 0.6) * dB
        if site.off_path(xy, 2.0) and site.off_roads(xy, 0.3):
            bollard(mb, xy, 0.0)
    texture = GroundTexture(roads, lambda p: 0.28 * (1.0 + 0.2 * grain(p, 0.5, 11)), salt=int(rng.integers(1 << 30)))
    return World("box_street", path, speed, roads, mb.finish(), lambda p: np.zeros(len(p)), texture,
                 {"buildings": n_buildings, "parked_cars": n_cars, "poles": n_poles, "turn_radius_m": radius,
                  "junction": "T, left turn", "ground": "flat, z = 0"})


# --- family: suburb -------------------------------------------------------------------------------
def suburb(rng, duration_s: float) -> World:
    speed = SpeedProgramme(6.0, ((2.0, 6.0), (2.5, 8.5), (1.5, 8.5), (2.5, 4.0), (4.5, 4.0), (2.5, 7.5)))
    speed = speed.extended(duration_s, rng)
    s_turn = float(speed.evaluate(np.array([8.6]))[0][0])
    radius = float(rng.uniform(8.0, 9.5))
    bends = [("straight", 4.0), ("turn", float(rng.uniform(9, 14)), float(rng.uniform(55, 75)), 6.0),
             ("straight", 4.0), ("turn", -float(rng.uniform(12, 17)), float(rng.uniform(65, 85)), 6.0)]
    pre = sum(b[1] if b[0] == "straight" else np.radians(abs(b[1])) * b[2] + b[3] for b in bends)
    plan = bends + [("straight", max(s_turn - pre, 4.0)), ("turn", 90.0, radius, 3.0), ("straight", 15.0),
                    ("turn", -10.0, 120.0, 10.0)]
    s_lo, s_hi = _drive_span(speed, duration_s)
    path, turns = path_from_plan(plan, s_lo - REACH_M - 20, s_hi + REACH_M + 20)
    t0, t1 = turns[2]
    J, dA, dB = junction(path, t0, t1)
    hw = 3.5
    far = REACH_M + 30
    main = Road(np.vstack([path.offset(s_lo - REACH_M - 15, t0, LANE_OFFSET_M), J, J + far * dA]), hw,
                centre="dashed" if rng.random() < 0.5 else "none", asphalt=rng.uniform(0.1, 0.2))
    side_road = Road(np.vstack([J, path.offset(t1, max(s_hi + REACH_M + 15, t1 + 1.0), LANE_OFFSET_M)]), hw,
                     centre="none", asphalt=rng.uniform(0.1, 0.2))
    roads = [main, side_road]
    grade = rng.uniform(-0.025, 0.025, 2)
    camber = rng.uniform(0.02, 0.03)

    def ground_z(p):
        p = np.asarray(p)[:, :2]
        d = np.min([r.distance(p) for r in roads], axis=0)
        on_road = -camber * np.minimum(d, hw)
        verge = 0.02 * np.clip(d - hw, 0.0, 2.0) + 0.03 * np.clip(d - hw - 2.0, 0.0, 12.0)
        return p @ grade + on_road + verge

    site = Site(path, s_lo, s_hi, roads)
    mb = MeshBuilder()
    n_tri_ground = height_field_ground(mb, site, ground_z, cell=1.0)
    counts = {"houses": 0, "trees": 0, "hedges": 0, "fences": 0, "parked_cars": 0}
    for road in roads:
        for side in (1.0, -1.0):
            s = rng.uniform(-10.0, 10.0)
            while s < road.length:
                plot = rng.uniform(16.0, 24.0)
                frame = frame_on(road, s + plot / 2, side)
                s += plot
                prop = rng.uniform(5.8, 7.0)          # front property line
                setback = rng.uniform(8.0, 15.0)      # front wall of the house
                w, depth = rng.uniform(9.0, min(13.0, plot - 3.0)), rng.uniform(8.0, 11.0)
                off = rng.uniform(-(plot - w) / 2 + 1.0, (plot - w) / 2 - 1.0)
                plot_fp = footprint(frame, -plot / 2, plot / 2, prop, setback + depth)
                if not (site.near(frame.origin).all() and site.off_roads(plot_fp, 1.5, skip=road)
                        and site.off_path(plot_fp, 3.0)):
                    continue
                zb = float(ground_z(frame.pt(off, setback + depth / 2, 0)[None, :2])[0])
                gable_house(mb, frame, off - w / 2, off + w / 2, setback, setback + depth, zb, rng)
                counts["houses"] += 1
                drive_u = rng.uniform(-plot / 2 + 2.0, plot / 2 - 5.5)  # driveway gap in the hedge
                z_front = float(ground_z(frame.pt(0, prop, 0)[None, :2])[0])
                kind = rng.choice(["hedge", "fence", "none"], p=[0.5, 0.3, 0.2])
                for a, b in ((-plot / 2, drive_u), (drive_u + 3.5, plot / 2)):
                    if b - a < 0.5:
                        continue
                    if kind == "hedge":
                        hh = rng.uniform(0.9, 1.6)
                        mb.box(frame, a, b, prop, prop + rng.uniform(0.6, 1.0), z_front - 0.3, z_front + hh,
                               rng.uniform(0.35, 0.45), M.VEGETATION)
                        counts["hedges"] += 1
                    elif kind == "fence":
                        mb.box(frame, a, b, prop, prop + 0.05, z_front - 0.3, z_front + rng.uniform(1.0, 1.3),
                               rng.uniform(0.3, 0.4), M.WOOD)
                        counts["fences"] += 1
                if rng.random() < 0.45:  # a car on the driveway, nose to the house
                    cf = Frame(frame.origin, frame.v, frame.u)
                    car(mb, cf, prop + 3.2, drive_u + 1.75, z_front, rng)
                    counts["parked_cars"] += 1
                for _ in range(rng.integers(0, 3)):  # garden trees
                    tu = rng.uniform(-plot / 2 + 1.5, plot / 2 - 1.5)
                    tv = rng.uniform(prop + 2.0, setback + depth + 4.0)
                    if setback - 1.5 < tv < setback + depth + 1.5 and abs(tu - off) < w / 2 + 1.5:
                        continue
                    xy = frame.pt(tu, tv, 0)[:2]
                    tree(mb, xy, float(ground_z(xy[None])[0]), rng)
                    counts["trees"] += 1
            s = rng.uniform(0.0, 20.0)
            while s < road.length:  # street trees and cars on the verge
                frame = frame_on(road, s, side)
                s += rng.uniform(14.0, 26.0)
                if not site.near(frame.origin).all():
                    continue
                if rng.random() < 0.35:
                    xy = frame.pt(0.0, hw + 1.2, 0)[:2]
                    if site.off_roads(xy[None], 1.0, skip=road) and site.off_path(xy[None], 3.0):
                        tree(mb, xy, float(ground_z(xy[None])[0]), rng, scale=0.9)
                        counts["trees"] += 1
                elif rng.random() < 0.3:
                    fp = footprint(frame, 3.0, 8.0, hw + 0.9 - 1.0, hw + 0.9 + 1.0)
                    if site.off_roads(fp, 0.5, skip=road) and site.off_path(fp, 1.4):
                        z0 = float(ground_z(frame.pt(5.5, hw + 0.9, 0)[None, :2])[0])
                        car(mb, frame, 5.5, hw + 0.9, z0, rng)
                        counts["parked_cars"] += 1
    texture = GroundTexture(roads, _suburb_offroad(roads, hw), salt=int(rng.integers(1 << 30)))
    return World("suburb", path, speed, roads, mb.finish(), ground_z, texture,
                 {**counts, "turn_radius_m": radius, "camber": float(camber), "grade": grade.tolist(),
                  "ground_triangles": n_tri_ground, "junction": "T, left turn into a side street"})


def _suburb_offroad(roads, hw):
    def offroad(p):
        d = np.min([r.distance(p) for r in roads], axis=0)
        pavement = 0.3 * (1.0 + 0.15 * grain(p, 0.4, 21))
        grass = 0.42 * (1.0 + 0.3 * grain(p, 0.15, 22) + 0.1 * grain(p, 2.0, 23))
        return np.where(d < hw + 2.0, pavement, grass)
    return offroad


# --- family: open road -------------------------------------------------------------------------------
def open_road(rng, duration_s: float) -> World:
    speed = SpeedProgramme(8.0, ((1.5, 8.0), (3.0, 12.0), (1.5, 12.0), (2.0, 9.5), (4.5, 9.5), (3.0, 11.0)))
    speed = speed.extended(duration_s, rng)
    s_bend = float(speed.evaluate(np.array([7.6]))[0][0])
    radius = float(rng.uniform(50.0, 65.0))
    bend = float(rng.uniform(35.0, 50.0)) * (1 if rng.random() < 0.6 else -1)
    s_lo, s_hi = _drive_span(speed, duration_s)
    path, turns = path_from_plan([("straight", s_bend), ("turn", bend, radius, 15.0)],
                                 s_lo - REACH_M - 20, s_hi + REACH_M + 20)
    hw = 3.75
    road = Road(path.offset(s_lo - REACH_M - 15, s_hi + REACH_M + 15, LANE_OFFSET_M), hw, centre="dashed",
                edges=True, asphalt=rng.uniform(0.1, 0.18))
    roads = [road]
    kappa_max = 1.0 / radius
    # the road's curvature at its own s (the road starts at path s = s_lo - REACH_M - 15)
    road_s0 = s_lo - REACH_M - 15
    grade_dir = np.array([np.cos(np.radians(bend / 2)), np.sin(np.radians(bend / 2))])
    grade = rng.uniform(0.008, 0.02) * (1 if rng.random() < 0.5 else -1)
    ditch_side = -1.0 if rng.random() < 0.7 else 1.0
    emb_h = rng.uniform(2.0, 3.5)
    ditch_d = rng.uniform(0.8, 1.4)
    # cross profile outside the road, by lateral distance beyond the shoulder (m), per side
    ditch_knots = ([0.0, 3.0, 4.0, 7.0, 80.0], [0.0, -ditch_d, -ditch_d, 0.3, 0.3])
    emb_knots = ([0.0, 2.0 * emb_h, 80.0], [0.0, emb_h, emb_h])

    def ground_z(p):
        p = np.asarray(p)[:, :2]
        s, lat, _ = road.project(p)
        w = np.abs(path.kappa(s + road_s0)) / kappa_max  # superelevation weight in the bend
        turn_sign = np.sign(bend)
        crown = -0.02 * np.minimum(np.abs(lat), hw + 1.0)
        superelevation = -0.035 * turn_sign * np.clip(lat, -(hw + 1.0), hw + 1.0)
        z_road = (1 - w) * crown + w * superelevation
        beyond = np.maximum(np.abs(lat) - (hw + 1.0), 0.0)
        ditch = np.interp(beyond, *ditch_knots)
        emb = np.interp(beyond, *emb_knots)
        z_side = np.where(np.sign(lat) == ditch_side, ditch, emb)
        fields = np.clip((beyond - 12.0) / 10.0, 0, 1)
        undulation = 0.35 * np.sin(p[:, 0] / 23.0 + 1.3) * np.cos(p[:, 1] / 31.0) * fields
        return grade * (p @ grade_dir) + z_road + z_side + undulation

    site = Site(path, s_lo, s_hi, roads)
    mb = MeshBuilder()
    n_tri_ground = height_field_ground(mb, site, ground_z, cell=1.0)
    counts = {"guard_rail_m": 0.0, "sign_posts": 0, "delineators": 0, "trees": 0, "buildings": 0, "fence_posts": 0}
    # guard rail on the ditch side at the shoulder's edge, in runs with gaps
    s = rng.uniform(0.0, 30.0)
    while s < road.length:
        run = rng.uniform(40.0, 90.0)
        ss = np.arange(s, min(s + run, road.length), 1.0)
        s += run + rng.uniform(15.0, 40.0)
        if len(ss) < 3:
            continue
        pts = np.array([road.point(v)[0] for v in ss])
        if not site.near(pts).any():
            continue
        tangents = np.array([road.point(v)[1] for v in ss])
        normal = ditch_side * np.column_stack([-tangents[:, 1], tangents[:, 0]])
        at = pts + (hw + 0.75) * normal
        zg = ground_z(at)
        for dz0, dz1, dv0, dv1 in ((0.45, 0.6, 0.0, -0.08), (0.6, 0.75, -0.08, 0.0)):
            bottom = np.column_stack([at + dv0 * normal, zg + dz0])
            top = np.column_stack([at + dv1 * normal, zg + dz1])
            mb.ribbon(bottom, top, rng.uniform(0.6, 0.8), M.RAIL)
        for k in range(0, len(ss), 2):
            frame = Frame.at(at[k], tangents[k], ditch_side)
            mb.box(frame, -0.05, 0.05, 0.02, 0.17, zg[k] - 0.3, zg[k] + 0.72, 0.4, M.METAL)
        counts["guard_rail_m"] += float(ss[-1] - ss[0])
    # delineator posts on the other side every 25 m, sign posts every 50-90 m
    for s in np.arange(rng.uniform(0, 25), road.length, 25.0):
        frame = frame_on(road, s, -ditch_side)
        if not site.near(frame.origin).all():
            continue
        zg = float(ground_z(frame.pt(0, hw + 1.2, 0)[None, :2])[0])
        mb.box(frame, -0.06, 0.06, hw + 1.14, hw + 1.26, zg - 0.2, zg + 1.0, 0.8, M.CONCRETE)
        mb.box(frame, -0.065, -0.06, hw + 1.16, hw + 1.24, zg + 0.75, zg + 0.93, 0.9, M.SIGN)
        counts["delineators"] += 1
    s = rng.uniform(10.0, 60.0)
    while s < road.length:
        side = 1.0 if rng.random() < 0.5 else -1.0
        frame = frame_on(road, s, side)
        s += rng.uniform(50.0, 90.0)
        v = hw + rng.uniform(1.6, 2.4)
        if not site.near(frame.origin).all() or not site.off_path(frame.pt(0, v, 0)[None, :2], 3.0):
            continue
        zg = float(ground_z(frame.pt(0, v, 0)[None, :2])[0])
        height = rng.uniform(2.0, 2.6)
        mb.cylinder(frame.pt(0, v, zg - 0.3), [0, 0, 1], 0.04, height + 0.3, 0.5, M.METAL, sides=8)
        a = rng.uniform(0.3, 0.45)
        facing = -side  # the plate faces the traffic coming along +u on this side
        mb.box(frame, facing * 0.06 - 0.01, facing * 0.06 + 0.01, v - a, v + a, zg + height - 2 * a,
               zg + height, 0.9, M.SIGN)
        counts["sign_posts"] += 1
    # a fence line along the fields, trees, a warehouse and a farmhouse
    fence_lat = -ditch_side * (hw + 2.0 * emb_h + rng.uniform(4.0, 8.0))
    for s in np.arange(0.0, road.length, 4.0):
        xy, t = road.point(s)
        p = xy + fence_lat * np.array([-t[1], t[0]])
        if site.near(p).all():
            zg = float(ground_z(p[None])[0])
            mb.box(Frame.at(p, t, 1.0), -0.04, 0.04, -0.04, 0.04, zg - 0.2, zg + 1.2, 0.35, M.WOOD)
            counts["fence_posts"] += 1
    for _ in range(rng.integers(4, 10)):
        s = rng.uniform(0.0, road.length)
        side = 1.0 if rng.random() < 0.5 else -1.0
        xy, t = road.point(s)
        p = xy + side * rng.uniform(12.0, 45.0) * np.array([-t[1], t[0]])
        if site.near(p).all() and site.off_roads(p, 6.0) and site.off_path(p, 10.0):
            tree(mb, p, float(ground_z(p[None])[0]), rng, scale=rng.uniform(1.0, 1.5))
            counts["trees"] += 1
    s_mid = -road_s0 + (s_hi + s_lo) / 2  # near the middle of the drive, on the road's s
    for kind, lat_range, side in (("warehouse", (40.0, 60.0), -ditch_side), ("farmhouse", (25.0, 40.0), ditch_side)):
        for _attempt in range(10):
            s = s_mid + rng.uniform(-60.0, 60.0)
            frame = frame_on(road, s, side)
            v0 = rng.uniform(*lat_range)
            if kind == "warehouse":
                w, depth = rng.uniform(40.0, 60.0), rng.uniform(20.0, 30.0)
            else:
                w, depth = rng.uniform(10.0, 14.0), rng.uniform(8.0, 11.0)
            fp = footprint(frame, -w / 2, w / 2, v0, v0 + depth)
            if site.off_roads(fp, 15.0):
                zb = float(np.min(ground_z(fp)))
                if kind == "warehouse":
                    wall = rng.uniform(8.0, 11.0)
                    gable_house(mb, frame, -w / 2, w / 2, v0, v0 + depth, zb, rng, eave=wall, ridge=wall + 1.5,
                                along=True, wall_refl=rng.uniform(0.4, 0.6), roof_refl=0.3, roof_mat=M.METAL,
                                overhang=0.3)
                else:
                    gable_house(mb, frame, -w / 2, w / 2, v0, v0 + depth, zb, rng)
                counts["buildings"] += 1
                break

    def offroad(p):
        _, lat, _ = road.project(p)
        gravel = 0.3 * (1.0 + 0.3 * grain(p, 0.1, 31))
        field = 0.35 * (1.0 + 0.35 * grain(p, 0.2, 32) + 0.2 * grain(p, 3.0, 33))
        return np.where(np.abs(lat) < hw + 1.0, gravel, field)

    texture = GroundTexture(roads, offroad, salt=int(rng.integers(1 << 30)))
    return World("open_road", path, speed, roads, mb.finish(), ground_z, texture,
                 {**counts, "bend_deg": bend, "bend_radius_m": radius, "grade": float(grade),
                  "ditch_side": "right" if ditch_side < 0 else "left", "embankment_m": float(emb_h),
                  "ground_triangles": n_tri_ground})


# --- family: relief street ------------------------------------------------------------------------
def relief_building(mb: MeshBuilder, frame: Frame, w: float, f: float, depth: float, height: float, z0: float,
                    rng) -> dict:
    """A city building on the frame's u in [-w/2, w/2], its facade line at v = f, depth along v.

    Recessed windows, piers and spandrels, optional pilasters, string course, cornice with a
    chamfered underside, balconies at 3, 6, 9 m, and a shop front on the ground floor."""
    wall = rng.uniform(0.3, 0.6)
    balconies = rng.random() < 0.5
    fh = 3.0 if balconies else rng.uniform(3.0, 3.4)
    floors = max(3, int((height - 0.8) / fh))
    top = z0 + floors * fh + rng.uniform(0.6, 1.2)
    shop = rng.random() < 0.7
    n_bays = max(2, int(round(w / rng.uniform(2.8, 3.6))))
    bw = w / n_bays
    ww = bw * rng.uniform(0.4, 0.55)
    r_win = rng.uniform(0.1, 0.3)
    r_shop = rng.uniform(0.3, 0.6)
    u0, u1 = -w / 2, w / 2
    centres = u0 + bw * (np.arange(n_bays) + 0.5)
    glass = rng.uniform(0.05, 0.12)
    # cores: upper floors behind the window plane, ground floor behind the shop glass
    first = z0 + fh if shop else z0 - 0.3
    mb.box(frame, u0, u1, f + r_win, f + depth, first, top, wall, M.FACADE)
    if shop:
        mb.box(frame, u0, u1, f + r_shop, f + depth, z0 - 0.3, z0 + fh, wall, M.FACADE)
    window_floors = range(1 if shop else 0, floors)
    sills = [z0 + k * fh + 0.9 for k in window_floors]
    heads = [z0 + k * fh + 2.4 for k in window_floors]
    # spandrel bands from the facade line back to the window plane
    bands = [(first if shop else z0 - 0.3, sills[0])] + list(zip(heads[:-1], sills[1:])) + [(heads[-1], top)]
    for a, b in bands:
        mb.box(frame, u0, u1, f, f + r_win, a, b, wall, M.FACADE)
    pier = bw - ww
    for k in range(n_bays + 1):
        c = u0 + k * bw
        mb.box(frame, max(u0, c - pier / 2), min(u1, c + pier / 2), f, f + r_win, first, top, wall, M.FACADE)
    for a, b in zip(sills, heads):  # the panes, 1 cm in front of the core
        for c in centres:
            mb.quad(frame.pt(c - ww / 2, f + r_win - 0.01, a), frame.pt(c + ww / 2, f + r_win - 0.01, a),
                    frame.pt(c + ww / 2, f + r_win - 0.01, b), frame.pt(c - ww / 2, f + r_win - 0.01, b),
                    glass, M.GLASS)
    if shop:
        for k in range(n_bays + 1):  # shop piers
            c = u0 + k * bw
            mb.box(frame, max(u0, c - 0.3), min(u1, c + 0.3), f, f + r_shop, z0 - 0.3, z0 + fh, wall, M.FACADE)
        for c in centres:
            a, b = c - bw / 2 + 0.3, c + bw / 2 - 0.3
            mb.quad(frame.pt(a, f + r_shop - 0.01, z0 + 0.5), frame.pt(b, f + r_shop - 0.01, z0 + 0.5),
                    frame.pt(b, f + r_shop - 0.01, z0 + fh - 0.7), frame.pt(a, f + r_shop - 0.01, z0 + fh - 0.7),
                    glass, M.GLASS)
        mb.box(frame, u0, u1, f - 0.12, f + r_shop, z0 + fh - 0.7, z0 + fh, rng.uniform(0.5, 0.9), M.FACADE)
    else:
        mb.box(frame, u0, u1, f - 0.08, f, z0 + fh - 0.05, z0 + fh + 0.2, wall, M.FACADE)  # string course
    if rng.random() < 0.6:  # pilasters
        every = int(rng.integers(1, 4))
        pw, pp = rng.uniform(0.4, 0.7), rng.uniform(0.15, 0.35)
        for k in range(0, n_bays + 1, every):
            c = u0 + k * bw
            mb.box(frame, max(u0, c - pw / 2), min(u1, c + pw / 2), f - pp, f, z0 + (fh if shop else 0.0) - 0.05,
                   top - 0.3, wall, M.FACADE)
    c, ch = rng.uniform(0.3, 0.6), rng.uniform(0.35, 0.6)  # cornice, chamfered underside
    bottom = frame.pt([u0, u1, u1, u0], [f - c, f - c, f + 0.01, f + 0.01],
                      [top - 0.4 * ch, top - 0.4 * ch, top - ch, top - ch])
    upper = frame.pt([u0, u1, u1, u0], [f - c, f - c, f + 0.01, f + 0.01], [top] * 4)
    mb.hexahedron(np.vstack([bottom, upper]), wall, M.FACADE)
    n_balconies = 0
    if balconies:
        pattern = rng.choice(["all", "alternate"])
        for k in (1, 2, 3):
            if k >= floors:
                break
            zb = z0 + 3.0 * k
            for i, cb in enumerate(centres):
                if pattern == "alternate" and i % 2:
                    continue
                a, b = max(u0, cb - ww / 2 - 0.4), min(u1, cb + ww / 2 + 0.4)
                mb.box(frame, a, b, f - 0.8, f, zb - 0.15, zb, wall, M.CONCRETE)
                mb.box(frame, a, b, f - 0.8, f - 0.76, zb, zb + 1.0, 0.45, M.METAL)
                mb.box(frame, a, a + 0.04, f - 0.8, f, zb, zb + 1.0, 0.45, M.METAL)
                mb.box(frame, b - 0.04, b, f - 0.8, f, zb, zb + 1.0, 0.45, M.METAL)
                n_balconies += 1
    return {"floors": floors, "shop": bool(shop), "balconies": n_balconies}


def relief_street(rng, duration_s: float) -> World:
    speed = SpeedProgramme(5.0, ((1.5, 5.0), (3.0, 8.5), (2.0, 8.5), (2.5, 4.0), (4.0, 4.0), (2.5, 7.5)))
    speed = speed.extended(duration_s, rng)
    s_turn = float(speed.evaluate(np.array([9.1]))[0][0])
    radius = float(rng.uniform(8.0, 9.0))
    s_lo, s_hi = _drive_span(speed, duration_s)
    path, turns = path_from_plan([("straight", s_turn), ("turn", 90.0, radius, 3.0)],
                                 s_lo - REACH_M - 20, s_hi + REACH_M + 20)
    (t0, t1), = turns
    J, dA, dB = junction(path, t0, t1)
    hw = 5.5
    kerb = 0.15
    far = REACH_M + 30
    road_a = Road(np.vstack([path.offset(s_lo - REACH_M - 15, t0, LANE_OFFSET_M), J, J + far * dA]), hw,
                  centre="dashed", asphalt=rng.uniform(0.1, 0.2))
    road_b = Road(np.vstack([J - far * dB, path.offset(t1, max(s_hi + REACH_M + 15, t1 + 1.0), LANE_OFFSET_M)]),
                  hw, centre="dashed", asphalt=rng.uniform(0.1, 0.2))
    roads = [road_a, road_b]
    site = Site(path, s_lo, s_hi, roads)
    mb = MeshBuilder()
    flat_ground(mb, site.bbox)
    # raised pavements: the four quadrants between the roads (the roads are axis-aligned here)
    assert abs(dA[1]) < 1e-6 and abs(dB[0]) < 1e-6, "relief_street expects a road along x and one along y"
    x0, x1, y0, y1 = site.bbox
    for xa, xb in ((x0, J[0] - hw), (J[0] + hw, x1)):
        for ya, yb in ((y0, J[1] - hw), (J[1] + hw, y1)):
            if xb > xa and yb > ya:
                mb.axis_box(xa, xb, ya, yb, -0.3, kerb, rng.uniform(0.25, 0.35), M.PAVEMENT)
    counts = {"buildings": 0, "shops": 0, "balconies": 0, "parked_cars": 0, "poles": 0}
    for road in roads:
        for side in (1.0, -1.0):
            s = rng.uniform(-5.0, 5.0)
            while s < road.length:
                w = rng.uniform(10.0, 22.0)
                frame = frame_on(road, s + w / 2, side)
                f, depth, h = rng.uniform(7.5, 10.0), rng.uniform(12.0, 15.0), rng.uniform(9.0, 24.0)
                fp = footprint(frame, -w / 2, w / 2, f - 0.9, f + depth)
                if site.near(frame.origin).all() and site.off_roads(fp, 1.0, skip=road) and site.off_path(fp, 4.0):
                    info = relief_building(mb, frame, w, f, depth, h, kerb, rng)
                    counts["buildings"] += 1
                    counts["shops"] += info["shop"]
                    counts["balconies"] += info["balconies"]
                s += w + rng.choice([0.0, 0.0, 0.0, 0.0, rng.uniform(1.5, 3.0)])
            s = rng.uniform(0.0, 8.0)
            while s < road.length:
                length = 5.0 + rng.uniform(0.5, 3.0)
                if rng.random() < 0.65:
                    frame = frame_on(road, s, side)
                    fp = footprint(frame, -2.5, 2.5, 4.4 - 1.0, 4.4 + 1.0)
                    if site.near(frame.origin, 90.0).all() and site.off_roads(fp, 1.5, skip=road) \
                            and site.off_path(fp, 1.4):
                        car(mb, frame, 0.0, 4.4, 0.0, rng)
                        counts["parked_cars"] += 1
                s += length
            s = rng.uniform(0.0, 20.0)
            while s < road.length:
                frame = frame_on(road, s, side)
                s += rng.uniform(18.0, 28.0)
                p = frame.pt(0, hw + 0.7, 0)[None, :2]
                if site.near(frame.origin).all() and site.off_roads(p, 0.5, skip=road) and site.off_path(p, 2.0):
                    if rng.random() < 0.75:
                        lamp_post(mb, frame, hw + 0.7, kerb, rng)
                    else:  # a sign pole
                        mb.cylinder(frame.pt(0, hw + 0.7, 0.0), [0, 0, 1], 0.035, 2.8, 0.5, M.METAL, sides=8)
                        mb.box(frame, -0.01, 0.01, hw + 0.4, hw + 1.0, 2.2, 2.8, 0.9, M.SIGN)
                    counts["poles"] += 1
    texture = GroundTexture(roads, lambda p: 0.3 * (1.0 + 0.2 * grain(p, 0.3, 41)), salt=int(rng.integers(1 << 30)))
    return World("relief_street", path, speed, roads, mb.finish(), lambda p: np.zeros(len(p)), texture,
                 {**counts, "turn_radius_m": radius, "junction": "crossing, left turn", "kerb_m": kerb,
                  "ground": "road z = 0, pavements z = 0.15"})


BUILDERS = {"box_street": box_street, "suburb": suburb, "open_road": open_road, "relief_street": relief_street}
FAMILIES = tuple(BUILDERS)


def build_world(family: str, rng, duration_s: float) -> World:
    if family not in BUILDERS:
        raise ValueError(f"unknown scene family {family!r}; known: {', '.join(FAMILIES)}")
    return BUILDERS[family](rng, duration_s)
