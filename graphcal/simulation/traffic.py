"""Moving traffic: vehicles and pedestrians as boxes on piecewise-linear paths, cast ray by ray at each
return's own time.

Coordinates are the simulator's local frame (x east, y north, z up [m]); times are seconds from the
scenario's start_time_s. A Mover is an upright box (size along, across, up [m]) whose base centre follows
its knots [(time s, x m, y m), ...] linearly (standing still before the first and after the last) at a
fixed yaw. The rays of a chunk are intersected with each box where it is at the ray's own time (an exact
slab test in the box's frame, numpy), so an object moves during a revolution as it does in a real scan.

TrafficSpec draws the movers of one straight street from a seed: vehicles overtaking the drive in its lane
and oncoming in the other, pedestrians walking along the sidewalks and crossing the street, each meeting
the vehicle that carries the lidar at a time drawn across the drive (stratified: they come evenly).
"""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

_FROZEN = ConfigDict(frozen=True, extra="forbid")
Vec2 = tuple[float, float]

VEHICLE_SIZE_M = (4.5, 1.8, 1.5)
PEDESTRIAN_SIZE_M = (0.5, 0.5, 1.8)


class Mover(BaseModel):
    """An upright box [m] (length along yaw, width, height) whose base centre follows knots (time s from the
    scenario's start, x m, y m) linearly, base_z_m [m] above z = 0, at yaw_deg (counter-clockwise from x)."""

    model_config = _FROZEN
    kind: str = Field("vehicle", pattern="^(vehicle|pedestrian)$")
    size_m: tuple[float, float, float] = Field(VEHICLE_SIZE_M)
    knots: list[tuple[float, float, float]] = Field(min_length=1, description="(time s, x m, y m), times increasing")
    yaw_deg: float = 0.0
    base_z_m: float = 0.0
    reflectivity: float = Field(0.5, gt=0, le=1)

    @model_validator(mode="after")
    def _check(self) -> Mover:
        times = [t for t, _, _ in self.knots]
        if any(b <= a for a, b in zip(times, times[1:])):
            raise ValueError("knots: times must increase")
        if min(self.size_m) <= 0:
            raise ValueError("size_m: every side must be > 0 m")
        return self

    def position(self, elapsed_s: np.ndarray) -> np.ndarray:
        """(N,2) base centre xy [m] at elapsed_s [s from the scenario's start]."""
        knots = np.asarray(self.knots, dtype=np.float64)
        elapsed_s = np.asarray(elapsed_s, dtype=np.float64)
        return np.column_stack([np.interp(elapsed_s, knots[:, 0], knots[:, k]) for k in (1, 2)])


def cast_movers(movers: list[Mover], origins: np.ndarray, directions: np.ndarray, elapsed_s: np.ndarray,
                max_range_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rays (origins (N,3) m, unit directions (N,3), local frame) each at its own time elapsed_s (N,) [s]
    against the movers -> (distance (N,) m, inf on a miss; mover index (N,), -1 on a miss; unit normal (N,3))."""
    n = len(origins)
    distance, index, normal = np.full(n, np.inf), np.full(n, -1), np.zeros((n, 3))
    if not movers or n == 0:
        return distance, index, normal
    t_span = np.array([elapsed_s.min(), elapsed_s.max()])
    centre_of_rays = origins.mean(axis=0)
    reach = np.linalg.norm(origins - centre_of_rays, axis=1).max() + max_range_m
    for k, mover in enumerate(movers):
        half = np.asarray(mover.size_m) / 2
        radius = float(np.linalg.norm(half))
        ends = mover.position(t_span)
        travel = float(np.linalg.norm(ends[1] - ends[0]))
        if np.linalg.norm(ends.mean(axis=0) - centre_of_rays[:2]) > reach + radius + travel:
            continue
        xy = mover.position(elapsed_s)
        centre = np.column_stack([xy, np.full(n, mover.base_z_m + half[2])])
        to_centre = centre - origins
        along = np.einsum("ni,ni->n", to_centre, directions)
        near = ((np.einsum("ni,ni->n", to_centre, to_centre) - along ** 2 < radius ** 2)
                & (along > -radius) & (along < max_range_m + radius))
        rows = np.flatnonzero(near)
        if not len(rows):
            continue
        t_hit, face = _slab(origins[rows] - centre[rows], directions[rows], half, np.radians(mover.yaw_deg))
        closer = t_hit < distance[rows]
        rows, t_hit, face = rows[closer], t_hit[closer], face[closer]
        distance[rows], index[rows], normal[rows] = t_hit, k, face
    return distance, index, normal


def _slab(offset: np.ndarray, directions: np.ndarray, half: np.ndarray, yaw_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """Ray-box intersection: rays from offset (N,3) [m, from the box's centre] along unit directions, the box
    of half sizes half [m] turned by yaw_rad about z -> (entry distance (N,) m, inf on a miss or from inside;
    the entered face's outward unit normal (N,3), world axes)."""
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    to_box = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])  # world axes -> box axes
    o, d = offset @ to_box.T, directions @ to_box.T
    with np.errstate(divide="ignore", invalid="ignore"):
        inverse = 1.0 / d
        t1, t2 = (-half - o) * inverse, (half - o) * inverse
    t1, t2 = np.nan_to_num(t1, nan=-np.inf), np.nan_to_num(t2, nan=np.inf)
    t_near_axes = np.minimum(t1, t2)
    axis = np.argmax(t_near_axes, axis=1)
    t_near = t_near_axes[np.arange(len(o)), axis]
    t_far = np.maximum(t1, t2).min(axis=1)
    hit = (t_near <= t_far) & (t_near > 0)
    local_normal = np.zeros_like(o)
    local_normal[np.arange(len(o)), axis] = -np.sign(d[np.arange(len(o)), axis])
    return np.where(hit, t_near, np.inf), local_normal @ to_box


class TrafficSpec(BaseModel):
    """Traffic along one straight street from street_start_xy to street_end_xy [m, local frame]: `vehicles`
    boxes of VEHICLE_SIZE_M in lanes lane_offset_m [m] right (overtaking, faster than the drive by
    overtake_speed_m_s) and left (oncoming at oncoming_speed_m_s) of the street's axis, half each; `pedestrians`
    boxes of PEDESTRIAN_SIZE_M, a crossing_fraction of them crossing the street ahead of the drive, the others
    walking along the sidewalks sidewalk_offset_m [m] from the axis, at pedestrian_speed_m_s. Each meets the
    drive at a time drawn (seed) in its own 1/n-th of the drive's span. Speeds are ranges [m/s]."""

    model_config = _FROZEN
    vehicles: int = Field(6, ge=0, le=1000)
    pedestrians: int = Field(10, ge=0, le=1000)
    seed: int = 0
    street_start_xy: Vec2 = (-100.0, 0.0)
    street_end_xy: Vec2 = (100.0, 0.0)
    lane_offset_m: float = Field(2.0, gt=0)
    sidewalk_offset_m: float = Field(6.8, gt=0)
    overtake_speed_m_s: tuple[float, float] = (2.0, 5.0)
    oncoming_speed_m_s: tuple[float, float] = (6.0, 12.0)
    pedestrian_speed_m_s: tuple[float, float] = (0.8, 1.6)
    crossing_fraction: float = Field(0.3, ge=0, le=1)
    crossing_ahead_m: tuple[float, float] = (8.0, 25.0)

    @model_validator(mode="after")
    def _check(self) -> TrafficSpec:
        for name in ("overtake_speed_m_s", "oncoming_speed_m_s", "pedestrian_speed_m_s", "crossing_ahead_m"):
            low, high = getattr(self, name)
            if not 0 <= low <= high:
                raise ValueError(f"{name}: give (low, high) with 0 <= low <= high")
        if np.hypot(*np.subtract(self.street_end_xy, self.street_start_xy)) < 1.0:
            raise ValueError("street_start_xy and street_end_xy must be at least 1 m apart")
        return self

    def movers(self, ego_xy, duration_s: float) -> list[Mover]:
        """The movers, meeting the drive whose position [m] at elapsed times (s) ego_xy(times) -> (N,2) gives."""
        rng = np.random.default_rng(self.seed)
        start, end = np.asarray(self.street_start_xy, float), np.asarray(self.street_end_xy, float)
        along = (end - start) / np.linalg.norm(end - start)
        left = np.array([-along[1], along[0]])
        yaw = float(np.degrees(np.arctan2(along[1], along[0])))
        times = np.linspace(0.0, duration_s, 201)
        ego_s = (ego_xy(times) - start) @ along
        ego_speed = float(np.median(np.gradient(ego_s, times)))
        ends = (-10.0, duration_s + 10.0)  # knots beyond the drive: the movers keep going through it

        def meets(n: int) -> np.ndarray:
            return (np.arange(n) + rng.uniform(0.0, 1.0, n)) / max(n, 1) * duration_s

        def line(t_meet, s_meet, speed, offset, size, yaw_deg, kind, reflectivity):
            knots = [(t, *(start + along * (s_meet + speed * (t - t_meet)) + left * offset)) for t in ends]
            return Mover(kind=kind, size_m=size, knots=knots, yaw_deg=yaw_deg, reflectivity=reflectivity)

        movers = []
        for k, t_meet in enumerate(meets(self.vehicles)):
            s_meet = float(np.interp(t_meet, times, ego_s))
            if k % 2 == 0:  # overtaking in the drive's lane side
                speed = ego_speed + rng.uniform(*self.overtake_speed_m_s)
                movers.append(line(t_meet, s_meet, speed, -self.lane_offset_m, VEHICLE_SIZE_M, yaw, "vehicle",
                                   rng.uniform(0.2, 0.9)))
            else:
                speed = -rng.uniform(*self.oncoming_speed_m_s)
                movers.append(line(t_meet, s_meet, speed, self.lane_offset_m, VEHICLE_SIZE_M, yaw + 180.0,
                                   "vehicle", rng.uniform(0.2, 0.9)))
        for t_meet in meets(self.pedestrians):
            s_meet = float(np.interp(t_meet, times, ego_s))
            speed = rng.uniform(*self.pedestrian_speed_m_s) * rng.choice([-1.0, 1.0])
            reflectivity = rng.uniform(0.2, 0.7)
            if rng.uniform() < self.crossing_fraction:
                # waits on one sidewalk, crosses (at the axis crossing_ahead_m ahead of the drive at t_meet), waits
                s_cross = s_meet + rng.uniform(*self.crossing_ahead_m)
                side, half_s = np.sign(speed) * self.sidewalk_offset_m, self.sidewalk_offset_m / abs(speed)
                steps = [(t_meet - half_s - 1e3, -side), (t_meet - half_s, -side), (t_meet + half_s, side),
                         (t_meet + half_s + 1e3, side)]
                knots = [(t, *(start + along * s_cross + left * offset)) for t, offset in steps]
                movers.append(Mover(kind="pedestrian", size_m=PEDESTRIAN_SIZE_M, knots=knots, yaw_deg=yaw + 90.0,
                                    reflectivity=reflectivity))
            else:
                side = rng.choice([-1.0, 1.0]) * self.sidewalk_offset_m
                movers.append(line(t_meet, s_meet, speed, side, PEDESTRIAN_SIZE_M, yaw, "pedestrian", reflectivity))
        return movers
