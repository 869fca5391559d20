"""Moving traffic: vehicles and pedestrians as boxes on piecewise-linear paths, cast ray by ray at each
return's own time.

Coordinates are the simulator's local frame (x east, y north, z up [m]); times are seconds from the
scenario's start_time_s. A Mover is an upright box (size along, across, up [m]) whose base centre follows
its knots [(time s, x m, y m), ...] linearly (standing still before the first and after the last) at a
fixed yaw. The rays of a chunk are intersected with each box where it is at the ray's own time (an exact
slab test in the box's frame, numpy), so an object moves during a revolution as it does in a real scan.

A mover given a span_s exists only within it (the rays of other times pass through its place): a drive of any
length holds its traffic as short-lived movers, and each chunk of rays is cast against those that exist then.

TrafficSpec draws the movers of one straight street from a seed: vehicles overtaking the drive in its lane
and oncoming in the other, pedestrians walking along the sidewalks and crossing the street, each meeting
the vehicle that carries the lidar at a time drawn across the drive (stratified: they come evenly).
DistrictTrafficSpec draws them on the streets of a grid district (graphcal/simulation/district.py) around a
drive that loops through it: vehicles overtaking, oncoming and crossing the drive's street, each driving its own
way through the grid for a while, pedestrians walking along the pavements and crossing the street.
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
    scenario's start, x m, y m) linearly, base_z_m [m] above z = 0, at yaw_deg (counter-clockwise from x).
    span_s (start s, end s from the scenario's start): it exists only then (None: always)."""

    model_config = _FROZEN
    kind: str = Field("vehicle", pattern="^(vehicle|pedestrian)$")
    size_m: tuple[float, float, float] = Field(VEHICLE_SIZE_M)
    knots: list[tuple[float, float, float]] = Field(min_length=1, description="(time s, x m, y m), times increasing")
    yaw_deg: float = 0.0
    base_z_m: float = 0.0
    reflectivity: float = Field(0.5, gt=0, le=1)
    span_s: tuple[float, float] | None = None

    @model_validator(mode="after")
    def _check(self) -> Mover:
        times = [t for t, _, _ in self.knots]
        if any(b <= a for a, b in zip(times, times[1:])):
            raise ValueError("knots: times must increase")
        if min(self.size_m) <= 0:
            raise ValueError("size_m: every side must be > 0 m")
        if self.span_s is not None and not self.span_s[0] <= self.span_s[1]:
            raise ValueError("span_s: give (start, end) with start <= end")
        return self

    @property
    def span(self) -> tuple[float, float]:
        """(start, end) [s from the scenario's start] of its existence, infinite without span_s."""
        return (-np.inf, np.inf) if self.span_s is None else self.span_s

    def position(self, elapsed_s: np.ndarray) -> np.ndarray:
        """(N,2) base centre xy [m] at elapsed_s [s from the scenario's start]."""
        knots = np.asarray(self.knots, dtype=np.float64)
        elapsed_s = np.asarray(elapsed_s, dtype=np.float64)
        return np.column_stack([np.interp(elapsed_s, knots[:, 0], knots[:, k]) for k in (1, 2)])


def cast_movers(movers: list[Mover], origins: np.ndarray, directions: np.ndarray, elapsed_s: np.ndarray,
                max_range_m: float | np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rays (origins (N,3) m, unit directions (N,3), local frame) each at its own time elapsed_s (N,) [s]
    against the movers (each where it is at the ray's time, and only while it exists), no farther than
    max_range_m [m] (or per ray (N,): where each hits the static scene) -> (distance (N,) m, inf on a miss;
    mover index (N,), -1 on a miss; unit normal (N,3)).

    A mover is tried on the rays that can reach it: the rays' origins lie within spread_m of their centre and the
    mover within `radius` of its centre during the rays' times, so seen from farther than their sum a ray's
    horizontal direction must point within asin(sum / distance) of it; a mover whose top is below every origin
    is tried on the rays pointing down only."""
    n = len(origins)
    distance, index, normal = np.full(n, np.inf), np.full(n, -1), np.zeros((n, 3))
    if not movers or n == 0:
        return distance, index, normal
    limit_m = np.broadcast_to(np.asarray(max_range_m, dtype=np.float64), (n,))
    t_span = np.array([elapsed_s.min(), elapsed_s.max()])
    centre_of_rays = origins.mean(axis=0)
    spread_m = np.linalg.norm(origins[:, :2] - centre_of_rays[:2], axis=1).max()
    reach = np.linalg.norm(origins - centre_of_rays, axis=1).max() + limit_m.max()
    lowest_origin_m = origins[:, 2].min()
    azimuth = np.arctan2(directions[:, 1], directions[:, 0])
    every_ray = _by_azimuth(np.arange(n), azimuth)
    down_rays = _by_azimuth(np.flatnonzero(directions[:, 2] < 0), azimuth)
    for k, mover in enumerate(movers):
        start, end = mover.span
        if start > t_span[1] or end < t_span[0]:
            continue
        half = np.asarray(mover.size_m) / 2
        box_radius = float(np.linalg.norm(half))
        knots = np.asarray(mover.knots)
        inside = knots[(knots[:, 0] > t_span[0]) & (knots[:, 0] < t_span[1]), 1:]
        ends = mover.position(t_span)
        middle = ends.mean(axis=0)
        radius = float(np.linalg.norm(half[:2]) + np.linalg.norm(np.r_[ends, inside] - middle, axis=1).max())
        away = middle - centre_of_rays[:2]
        if np.linalg.norm(away) > reach + radius:
            continue
        rays = down_rays if mover.base_z_m + mover.size_m[2] < lowest_origin_m else every_ray
        rows = _facing(*rays, away, radius + spread_m)
        if start > t_span[0] or end < t_span[1]:
            rows = rows[(elapsed_s[rows] >= start) & (elapsed_s[rows] <= end)]
        xy = mover.position(elapsed_s[rows])
        centre = np.column_stack([xy, np.full(len(rows), mover.base_z_m + half[2])])
        to_centre = centre - origins[rows]
        along = np.einsum("ni,ni->n", to_centre, directions[rows])
        near = ((np.einsum("ni,ni->n", to_centre, to_centre) - along ** 2 < box_radius ** 2)
                & (along > -box_radius) & (along < limit_m[rows] + box_radius))
        rows, centre = rows[near], centre[near]
        if not len(rows):
            continue
        t_hit, face = _slab(origins[rows] - centre, directions[rows], half, np.radians(mover.yaw_deg))
        closer = t_hit < distance[rows]
        rows, t_hit, face = rows[closer], t_hit[closer], face[closer]
        distance[rows], index[rows], normal[rows] = t_hit, k, face
    return distance, index, normal


def _by_azimuth(rays: np.ndarray, azimuth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ray indices sorted by their azimuth [rad], and those azimuths."""
    order = rays[np.argsort(azimuth[rays], kind="stable")]
    return order, azimuth[order]


def _facing(by_azimuth: np.ndarray, sorted_azimuth: np.ndarray, away_xy: np.ndarray, clear_m: float) -> np.ndarray:
    """The rays (ascending indices) whose azimuth [rad] is within asin(clear_m / distance) of the direction
    away_xy [m] (every ray when that is closer than clear_m); by_azimuth: the rays sorted by azimuth."""
    distance_m = float(np.linalg.norm(away_xy))
    if distance_m <= clear_m:
        return np.sort(by_azimuth)
    width = float(np.arcsin(clear_m / distance_m))
    low = float(np.arctan2(away_xy[1], away_xy[0])) - width
    windows = [(low, low + 2 * width)] + [(low + turn, low + turn + 2 * width) for turn in (-2 * np.pi, 2 * np.pi)]
    rows = [by_azimuth[np.searchsorted(sorted_azimuth, a, "left"):np.searchsorted(sorted_azimuth, b, "right")]
            for a, b in windows]
    return np.unique(np.concatenate(rows))


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


def meeting_times(n: int, duration_s: float, rng: np.random.Generator) -> np.ndarray:
    """n times [s] across the drive's duration_s, one drawn in each 1/n-th of it: the traffic comes evenly."""
    return (np.arange(n) + rng.uniform(0.0, 1.0, n)) / max(n, 1) * duration_s


def _check_ranges(spec: BaseModel, names: tuple[str, ...]) -> None:
    """Each named field is a range (low, high) with 0 <= low <= high, else ValueError."""
    for name in names:
        low, high = getattr(spec, name)
        if not 0 <= low <= high:
            raise ValueError(f"{name}: give (low, high) with 0 <= low <= high")


class _Traffic(BaseModel):
    """What traffic on a straight street and in a district share: the seed of every draw; vehicles in the lane
    lane_offset_m [m] right of a street's axis, the overtaking ones faster than the drive by overtake_speed_m_s;
    pedestrians at pedestrian_speed_m_s on the sidewalks sidewalk_offset_m [m] either side of the axis, a
    crossing_fraction of them crossing the street crossing_ahead_m [m] ahead of the drive. Ranges [m/s, m]."""

    model_config = _FROZEN
    seed: int = 0
    lane_offset_m: float = Field(2.0, gt=0)
    sidewalk_offset_m: float = Field(6.8, gt=0)
    overtake_speed_m_s: tuple[float, float] = (2.0, 5.0)
    pedestrian_speed_m_s: tuple[float, float] = (0.8, 1.6)
    crossing_fraction: float = Field(0.3, ge=0, le=1)
    crossing_ahead_m: tuple[float, float] = (8.0, 25.0)

    @model_validator(mode="after")
    def _check_common(self) -> _Traffic:
        _check_ranges(self, ("overtake_speed_m_s", "pedestrian_speed_m_s", "crossing_ahead_m"))
        return self


class TrafficSpec(_Traffic):
    """Traffic along one straight street from street_start_xy to street_end_xy [m, local frame]: `vehicles`
    boxes of VEHICLE_SIZE_M in lanes lane_offset_m [m] right (overtaking, faster than the drive by
    overtake_speed_m_s) and left (oncoming at oncoming_speed_m_s) of the street's axis, half each; `pedestrians`
    boxes of PEDESTRIAN_SIZE_M, a crossing_fraction of them crossing the street ahead of the drive, the others
    walking along the sidewalks sidewalk_offset_m [m] from the axis, at pedestrian_speed_m_s. Each meets the
    drive at a time drawn (seed) in its own 1/n-th of the drive's span. Speeds are ranges [m/s]."""

    vehicles: int = Field(6, ge=0, le=1000)
    pedestrians: int = Field(10, ge=0, le=1000)
    street_start_xy: Vec2 = (-100.0, 0.0)
    street_end_xy: Vec2 = (100.0, 0.0)
    oncoming_speed_m_s: tuple[float, float] = (6.0, 12.0)

    @model_validator(mode="after")
    def _check(self) -> TrafficSpec:
        _check_ranges(self, ("oncoming_speed_m_s",))
        if np.hypot(*np.subtract(self.street_end_xy, self.street_start_xy)) < 1.0:
            raise ValueError("street_start_xy and street_end_xy must be at least 1 m apart")
        return self

    def movers(self, ego_pose, duration_s: float) -> list[Mover]:
        """The movers, meeting the drive whose pose at elapsed times (s) ego_pose(times) -> (xyz (N,3) m, yaw (N,)
        deg) gives."""
        rng = np.random.default_rng(self.seed)
        start, end = np.asarray(self.street_start_xy, float), np.asarray(self.street_end_xy, float)
        along = (end - start) / np.linalg.norm(end - start)
        left = np.array([-along[1], along[0]])
        yaw = float(np.degrees(np.arctan2(along[1], along[0])))
        times = np.linspace(0.0, duration_s, 201)
        ego_s = (ego_pose(times)[0][:, :2] - start) @ along
        ego_speed = float(np.median(np.gradient(ego_s, times)))
        ends = (-10.0, duration_s + 10.0)  # knots beyond the drive: the movers keep going through it

        def line(t_meet, s_meet, speed, offset, size, yaw_deg, kind, reflectivity):
            knots = [(t, *(start + along * (s_meet + speed * (t - t_meet)) + left * offset)) for t in ends]
            return Mover(kind=kind, size_m=size, knots=knots, yaw_deg=yaw_deg, reflectivity=reflectivity)

        movers = []
        for k, t_meet in enumerate(meeting_times(self.vehicles, duration_s, rng)):
            s_meet = float(np.interp(t_meet, times, ego_s))
            if k % 2 == 0:  # overtaking in the drive's lane side
                speed = ego_speed + rng.uniform(*self.overtake_speed_m_s)
                movers.append(line(t_meet, s_meet, speed, -self.lane_offset_m, VEHICLE_SIZE_M, yaw, "vehicle",
                                   rng.uniform(0.2, 0.9)))
            else:
                speed = -rng.uniform(*self.oncoming_speed_m_s)
                movers.append(line(t_meet, s_meet, speed, self.lane_offset_m, VEHICLE_SIZE_M, yaw + 180.0,
                                   "vehicle", rng.uniform(0.2, 0.9)))
        for t_meet in meeting_times(self.pedestrians, duration_s, rng):
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


_LEFT = np.array([[0.0, -1.0], [1.0, 0.0]])  # turns a horizontal vector 90 deg counter-clockwise


class DistrictTrafficSpec(_Traffic):
    """Traffic on the streets of a grid district (graphcal/simulation/district.py): streets along the lines of
    crossings (i pitch_m, j pitch_m) [m, local frame], i in 0..blocks[0], j in 0..blocks[1], around a drive along
    their axes. vehicles_per_min and pedestrians_per_min [1/min of drive] meet the drive, each at a time drawn in
    its own share of the drive's span (moved on to the drive's next moment on a straight):

    - vehicles (VEHICLE_SIZE_M), in turn overtaking the drive (faster than it by overtake_speed_m_s), oncoming,
      and crossing its street at the nearest crossing at least clear_of_crossing_m [m] ahead (else behind) it,
      straight across or (where the cross street goes on one side only) turning there. Each drives in the lane
      lane_offset_m right of the axis at vehicle_speed_m_s, its own way through the grid (straight on, left or
      right at each crossing, never back nor off the grid), for life_s [s] before and after the meeting: one
      Mover per straight, with its span_s;
    - pedestrians (PEDESTRIAN_SIZE_M) at pedestrian_speed_m_s, a crossing_fraction of them crossing the drive's
      street crossing_ahead_m [m] ahead of it (at the crosswalk nearest there, crosswalk_m [m] from a crossing's
      centre, when given), 3 to 8 s before the drive gets there, waiting on the pavement before and after; the
      others walking along a pavement sidewalk_offset_m [m] either side of its axis (base pavement_z_m [m] up,
      through the crossings); each exists for life_s before and after its meeting or crossing.

    A mover whose box would come within clearance_m [m] of the drive's path (its body origin; a way that turns
    across the drive's at a crossing, a pedestrian crossing where it turns) is left out, its draws made all
    the same. Every draw comes from seed. Speeds and distances are ranges [m/s, m]."""

    blocks: tuple[int, int] = (2, 2)
    pitch_m: float = Field(56.0, gt=0)
    vehicles_per_min: float = Field(80.0, ge=0, le=6000)
    pedestrians_per_min: float = Field(60.0, ge=0, le=6000)
    pavement_z_m: float = Field(0.15, ge=0)
    vehicle_speed_m_s: tuple[float, float] = (6.0, 12.0)
    crosswalk_m: float | None = Field(None, gt=0)
    clear_of_crossing_m: float = Field(15.0, ge=0)
    life_s: float = Field(20.0, gt=0)
    clearance_m: float = Field(1.0, ge=0)

    @model_validator(mode="after")
    def _check(self) -> DistrictTrafficSpec:
        _check_ranges(self, ("vehicle_speed_m_s",))
        if min(self.blocks) < 1:
            raise ValueError("blocks: at least 1 x 1")
        if not self.lane_offset_m < self.sidewalk_offset_m < self.pitch_m / 2:
            raise ValueError("lane_offset_m < sidewalk_offset_m < pitch_m / 2: lanes inside the pavements, inside "
                             "the blocks' spacing")
        if self.vehicle_speed_m_s[0] <= 0 or self.pedestrian_speed_m_s[0] <= 0:
            raise ValueError("vehicle_speed_m_s and pedestrian_speed_m_s: movers must move (low end > 0 m/s)")
        return self

    def movers(self, ego_pose, duration_s: float) -> list[Mover]:
        """The movers, meeting the drive whose pose at elapsed times (s) ego_pose(times) -> (xyz (N,3) m, yaw (N,)
        deg) gives; the drive runs along the streets' axes but in its turns."""
        rng = np.random.default_rng(self.seed)
        times = np.arange(0.0, duration_s + 0.1, 0.1)
        xyz, yaw_deg = ego_pose(times)
        heading = np.round(np.column_stack([np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))]))
        across = np.where(np.abs(heading[:, 0]) > 0, xyz[:, 1], xyz[:, 0])
        straight = ((np.abs((yaw_deg + 45.0) % 90.0 - 45.0) < 0.5)
                    & (np.abs(across - self.pitch_m * np.round(across / self.pitch_m)) < 0.3))
        straight_at = np.flatnonzero(straight)
        if not len(straight_at):
            return []
        speed = np.gradient(np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(xyz[:, :2], axis=0), axis=1))], times)

        def on_straight(t: float) -> int:
            k = np.searchsorted(times[straight_at], t)
            return int(straight_at[min(k, len(straight_at) - 1)])

        def clear(legs: list[Mover]) -> list[Mover]:
            return legs if all(_gap_m(leg, times, xyz[:, :2]) >= self.clearance_m for leg in legs) else []

        movers = []
        n_vehicles = int(round(self.vehicles_per_min * duration_s / 60.0))
        for n, t_meet in enumerate(meeting_times(n_vehicles, duration_s, rng)):
            k = on_straight(t_meet)
            movers += clear(self._vehicle(n % 3, times[k], xyz[k, :2], heading[k], speed[k], rng))
        n_pedestrians = int(round(self.pedestrians_per_min * duration_s / 60.0))
        for t_meet in meeting_times(n_pedestrians, duration_s, rng):
            k = on_straight(t_meet)
            movers += clear([self._pedestrian(times, xyz[:, :2], k, heading[k], rng)])
        return movers

    def _on_grid(self, node: np.ndarray) -> bool:
        return bool(0 <= node[0] <= self.blocks[0] and 0 <= node[1] <= self.blocks[1])

    def _vehicle(self, role: int, t_meet: float, ego_xy: np.ndarray, heading: np.ndarray, ego_speed: float,
                 rng: np.random.Generator) -> list[Mover]:
        """One vehicle's legs (role 0 overtaking, 1 oncoming, 2 crossing), meeting the drive at ego_xy [m], heading
        along a street's axis (a unit axis vector) at t_meet [s]."""
        at, direction = ego_xy, heading
        if role == 2:
            at = self._crossing_near(ego_xy, heading)
            across = [w for w in (_LEFT @ heading, -_LEFT @ heading) if self._on_grid(np.round(at / self.pitch_m) + w)]
            direction = across[rng.integers(len(across))]
        if role == 0:
            speed = max(ego_speed, 0.0) + rng.uniform(*self.overtake_speed_m_s)
        else:
            speed = rng.uniform(*self.vehicle_speed_m_s)
            direction = -direction if role == 1 else direction
        reach_m = speed * self.life_s
        behind = self._walk(at, -direction, reach_m, rng)
        corners = behind[::-1] + self._walk(at, direction, reach_m, rng)[1:]
        lane = _lane(corners, self.lane_offset_m)
        travelled = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(lane, axis=0), axis=1))]
        meet = len(behind) - 1  # the meeting point's corner
        t = t_meet + (travelled - travelled[meet]) / speed
        reflectivity = rng.uniform(0.2, 0.9)
        legs = []
        for a, b in zip(range(len(lane) - 1), range(1, len(lane))):
            step = lane[b] - lane[a]
            if t[b] - t[a] < 1e-9:
                continue
            legs.append(Mover(kind="vehicle", size_m=VEHICLE_SIZE_M, knots=[(t[a], *lane[a]), (t[b], *lane[b])],
                              yaw_deg=float(np.degrees(np.arctan2(step[1], step[0]))), reflectivity=reflectivity,
                              span_s=(float(t[a]), float(t[b]))))
        return legs

    def _crossing_near(self, ego_xy: np.ndarray, heading: np.ndarray) -> np.ndarray:
        """The crossing [m] on the drive's street nearest it at least clear_of_crossing_m ahead, else behind."""
        side = np.abs(_LEFT @ heading)
        along = float(ego_xy @ heading)
        ahead = np.ceil((along + self.clear_of_crossing_m) / self.pitch_m) * self.pitch_m
        behind = np.floor((along - self.clear_of_crossing_m) / self.pitch_m) * self.pitch_m
        line_m = round(float(ego_xy @ side) / self.pitch_m) * self.pitch_m
        points = [heading * s + side * line_m for s in (ahead, behind)]
        return next((p for p in points if self._on_grid(np.round(p / self.pitch_m))),
                    np.clip(points[0], 0.0, np.multiply(self.blocks, self.pitch_m)))

    def _walk(self, start: np.ndarray, heading: np.ndarray, length_m: float,
              rng: np.random.Generator) -> list[np.ndarray]:
        """The corners [m] of a way of length_m along the streets' axes from start (on one) along heading (a unit
        axis vector), turning at random at the crossings (never back, never off the grid; at start first, if it is a
        crossing whose street does not go on along heading), start and end included."""
        corners, position, left_m = [np.asarray(start, float)], np.asarray(start, float), length_m
        node = np.round(position / self.pitch_m)
        if np.allclose(position, node * self.pitch_m) and not self._on_grid(node + heading):  # turns where it starts
            ways = [w for w in (_LEFT @ heading, -_LEFT @ heading) if self._on_grid(node + w)]
            heading = ways[rng.integers(len(ways))]
        while True:
            along = float(position @ heading)
            to_crossing = (np.floor(along / self.pitch_m + 1e-9) + 1) * self.pitch_m - along
            if to_crossing >= left_m:
                return corners + [position + heading * left_m]
            position, left_m = position + heading * to_crossing, left_m - to_crossing
            node = np.round(position / self.pitch_m)
            ways = [(w, p) for w, p in ((heading, 0.5), (_LEFT @ heading, 0.25), (-_LEFT @ heading, 0.25))
                    if self._on_grid(node + w)]
            weights = np.array([p for _, p in ways])
            turned = ways[rng.choice(len(ways), p=weights / weights.sum())][0]
            if turned @ heading < 0.5:
                corners.append(position)
            heading = turned

    def _pedestrian(self, times: np.ndarray, drive_xy: np.ndarray, k: int, heading: np.ndarray,
                    rng: np.random.Generator) -> Mover:
        """One pedestrian meeting the drive (at drive_xy (N,2) [m] at times (N,) [s]) at its k-th sample, heading
        along a street's axis. One that crosses does so ahead of the drive, and 3-8 s before it gets there."""
        t_meet, ego_xy = times[k], drive_xy[k]
        speed = rng.uniform(*self.pedestrian_speed_m_s) * rng.choice([-1.0, 1.0])  # along heading [m/s]
        reflectivity = rng.uniform(0.2, 0.7)
        side, yaw = _LEFT @ heading, float(np.degrees(np.arctan2(heading[1], heading[0])))
        along = float(ego_xy @ heading)  # the street runs from 0 to its length along its axis's sign
        low, high = sorted((0.0, self.blocks[int(np.argmax(np.abs(heading)))] * self.pitch_m * float(heading.sum())))
        life = (t_meet - self.life_s, t_meet + self.life_s)
        if rng.uniform() < self.crossing_fraction:
            # waits on one pavement, crosses (crossing_ahead_m ahead of the drive at t_meet), waits on the other
            s_cross = along + rng.uniform(*self.crossing_ahead_m)
            if self.crosswalk_m is not None:  # the nearest crosswalk, on either side of the nearest crossings
                node = np.round(s_cross / self.pitch_m) * self.pitch_m
                walks = node + np.array([-self.pitch_m + self.crosswalk_m, -self.crosswalk_m, self.crosswalk_m,
                                         self.pitch_m - self.crosswalk_m])
                walks = walks[(walks >= low) & (walks <= high)]
                s_cross = walks[np.argmin(np.abs(walks - s_cross))] if len(walks) else s_cross
            axis_point = ego_xy + heading * (np.clip(s_cross, low, high) - along)
            there = np.flatnonzero(np.linalg.norm(drive_xy[k:] - axis_point, axis=1) < 1.0)
            t_axis = times[k + there[0]] - rng.uniform(3.0, 8.0) if len(there) else t_meet
            offset, half_s = np.sign(speed) * self.sidewalk_offset_m, self.sidewalk_offset_m / abs(speed)
            knots = [(t_axis - half_s, *(axis_point - side * offset)), (t_axis + half_s, *(axis_point + side * offset))]
            return Mover(kind="pedestrian", size_m=PEDESTRIAN_SIZE_M, knots=knots, yaw_deg=yaw + 90.0,
                         reflectivity=reflectivity, span_s=(t_axis - self.life_s, t_axis + self.life_s))
        # along a pavement, while it goes on (through the crossings, to the district's outer pavements)
        offset = rng.choice([-1.0, 1.0]) * self.sidewalk_offset_m
        knots = [(t, *(ego_xy + heading * speed * (t - t_meet) + side * offset)) for t in life]
        ends_s = sorted(t_meet + (bound - along) / speed for bound in (low - self.sidewalk_offset_m,
                                                                       high + self.sidewalk_offset_m))
        return Mover(kind="pedestrian", size_m=PEDESTRIAN_SIZE_M, knots=knots, yaw_deg=yaw, base_z_m=self.pavement_z_m,
                     reflectivity=reflectivity, span_s=(max(life[0], ends_s[0]), min(life[1], ends_s[1])))


def _gap_m(mover: Mover, times_s: np.ndarray, xy_m: np.ndarray) -> float:
    """The least horizontal distance [m] from points xy_m (N,2) at times_s (N,) [s] to the mover's box, while it
    exists (inf if it never does then)."""
    start, end = mover.span
    now = (times_s >= start) & (times_s <= end)
    if not now.any():
        return np.inf
    yaw = np.radians(mover.yaw_deg)
    offset = xy_m[now] - mover.position(times_s[now])
    local = offset @ np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
    return float(np.linalg.norm(np.maximum(np.abs(local) - np.asarray(mover.size_m[:2]) / 2, 0.0), axis=1).min())


def _lane(corners: list[np.ndarray], offset_m: float) -> np.ndarray:
    """(K,2) the lane offset_m [m] right of a way along the streets' axes through corners [m]: at a turn the
    two lanes' crossing point, corners on a straight (the meeting point) moved across it."""
    corners = np.asarray(corners, dtype=np.float64)
    steps = np.diff(corners, axis=0)
    steps = steps / np.maximum(np.linalg.norm(steps, axis=1, keepdims=True), 1e-12)
    right = -steps @ _LEFT.T  # each step's right-hand normal
    lane = corners.copy()
    lane[0] += offset_m * right[0]
    lane[-1] += offset_m * right[-1]
    for k in range(1, len(corners) - 1):
        turned = steps[k - 1] @ steps[k] < 0.5
        lane[k] += offset_m * (right[k - 1] + right[k] if turned else right[k])
    return lane
