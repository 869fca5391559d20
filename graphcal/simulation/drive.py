"""Trajectory builders: a path (straights, arcs and turns on the spot) driven with a speed profile.

Local frame x east, y north, z up [m]; yaw counter-clockwise from x [deg]. The body frame is
x forward, y left, z up; the vehicle drives on flat ground (roll = pitch = 0).
"""

from __future__ import annotations

from typing import Annotated, Literal, NamedTuple

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from graphcal.common.errors import ConfigError


class Straight(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")
    kind: Literal["straight"] = "straight"
    length_m: float = Field(gt=0)


class Arc(BaseModel):
    """A circular arc; a positive angle turns left (counter-clockwise)."""

    model_config = ConfigDict(frozen=True, extra="forbid")
    kind: Literal["arc"] = "arc"
    radius_m: float = Field(gt=0)
    angle_deg: float

    @property
    def length_m(self) -> float:
        return self.radius_m * abs(np.radians(self.angle_deg))


class Spin(BaseModel):
    """A turn on the spot: the body origin stays where it is while the heading turns by angle_deg [deg]
    (positive left, counter-clockwise seen from above) at yaw_rate_deg_s [deg/s]. It covers no path
    (length 0 m) and takes |angle_deg| / yaw_rate_deg_s seconds, during which the drive's speed profile
    waits: the times of speed_knots count the time spent moving along the path."""

    model_config = ConfigDict(frozen=True, extra="forbid")
    kind: Literal["spin"] = "spin"
    angle_deg: float
    yaw_rate_deg_s: float = Field(gt=0)

    @field_validator("angle_deg")
    @classmethod
    def _turns(cls, value: float) -> float:
        if value == 0:
            raise ValueError("a spin must turn: angle_deg must not be 0")
        return value

    @property
    def length_m(self) -> float:
        return 0.0

    @property
    def duration_s(self) -> float:
        return abs(self.angle_deg) / self.yaw_rate_deg_s


Segment = Annotated[Straight | Arc | Spin, Field(discriminator="kind")]


def straight(length_m: float) -> list:
    return [Straight(length_m=length_m)]


def turn(radius_m: float, angle_deg: float) -> list:
    return [Arc(radius_m=radius_m, angle_deg=angle_deg)]


def spin(angle_deg: float, yaw_rate_deg_s: float) -> list:
    return [Spin(angle_deg=angle_deg, yaw_rate_deg_s=yaw_rate_deg_s)]


def loop(length_m: float, width_m: float, corner_radius_m: float) -> list:
    """A closed rounded rectangle driven counter-clockwise, length_m x width_m overall."""
    a, b = length_m - 2 * corner_radius_m, width_m - 2 * corner_radius_m
    if a <= 0 or b <= 0:
        raise ConfigError("loop: length and width must exceed twice the corner radius")
    return [Straight(length_m=a), Arc(radius_m=corner_radius_m, angle_deg=90.0),
            Straight(length_m=b), Arc(radius_m=corner_radius_m, angle_deg=90.0)] * 2


class Drive(BaseModel):
    """A path driven with a piecewise-linear speed profile [(time s from start, speed m/s), ...]."""

    model_config = ConfigDict(frozen=True, extra="forbid")
    segments: list[Segment]
    speed_knots: list[tuple[float, float]] = Field(description="(time s, speed m/s), times increasing")
    start_xy: tuple[float, float] = (0.0, 0.0)
    start_yaw_deg: float = 0.0
    height_m: float = Field(0.4, description="body origin above the ground [m]")

    @model_validator(mode="after")
    def _check(self) -> Drive:
        times = [t for t, _ in self.speed_knots]
        if not self.segments or not self.speed_knots:
            raise ValueError("a drive needs segments and at least one speed knot")
        if times[0] != 0.0 or any(b <= a for a, b in zip(times, times[1:])):
            raise ValueError("speed_knots: the first time must be 0 and times must increase")
        if any(v < 0 for _, v in self.speed_knots):
            raise ValueError("speed_knots: speeds must be >= 0 m/s")
        return self

    @property
    def length_m(self) -> float:
        return float(sum(seg.length_m for seg in self.segments))

    def distance(self, elapsed_s: np.ndarray) -> np.ndarray:
        """Arc length driven [m] after elapsed_s >= 0 seconds of the drive (exact for piecewise-linear speed;
        the last speed holds after the last knot; the arc length stays put while the vehicle spins)."""
        elapsed_s = np.asarray(elapsed_s, dtype=np.float64)
        moving_s = elapsed_s - sum(np.clip(elapsed_s - spin.start_s, 0.0, spin.duration_s) for spin in self._spins())
        t_knots, v_knots, s_knots = self._knots(moving_s.max(initial=0.0))
        k = np.clip(np.searchsorted(t_knots, moving_s, side="right") - 1, 0, len(t_knots) - 2)
        dt = moving_s - t_knots[k]
        slope = (v_knots[k + 1] - v_knots[k]) / (t_knots[k + 1] - t_knots[k])
        return s_knots[k] + v_knots[k] * dt + 0.5 * slope * dt * dt

    def pose_at(self, elapsed_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The pose after elapsed_s >= 0 seconds of the drive: (xyz (N,3) m, yaw (N,) deg), a spin's turn
        spread over its duration."""
        elapsed_s = np.asarray(elapsed_s, dtype=np.float64)
        s_m = self.distance(elapsed_s)
        xyz, yaw_deg = self.pose_at_distance(s_m)
        for spin in self._spins():  # pose_at_distance turns a whole spin once its arc length is reached
            done = np.clip((elapsed_s - spin.start_s) / spin.duration_s, 0.0, 1.0)
            yaw_deg = yaw_deg + spin.angle_deg * (done - (s_m >= spin.at_m))
        return xyz, yaw_deg

    def _knots(self, until_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The speed profile's knots: times [s] of moving along the path, speeds [m/s] and arc lengths [m], with a
        last knot past until_s [s] that holds the last speed."""
        t_knots = np.array([t for t, _ in self.speed_knots] + [max(self.speed_knots[-1][0], until_s) + 1.0])
        v_knots = np.array([v for _, v in self.speed_knots] + [self.speed_knots[-1][1]])
        s_knots = np.r_[0.0, np.cumsum(np.diff(t_knots) * (v_knots[1:] + v_knots[:-1]) / 2)]
        return t_knots, v_knots, s_knots

    def _moving_time_at(self, s_m: float) -> float:
        """The first time [s] of moving along the path at which the speed profile has covered s_m [m]."""
        t_knots, v_knots, s_knots = self._knots(0.0)
        if s_m > s_knots[-1]:  # past the knots, at the last speed
            if v_knots[-1] == 0:
                raise ConfigError(f"the drive stops after {s_knots[-1]:.1f} m, short of its spin at {s_m:.1f} m")
            return float(t_knots[-1] + (s_m - s_knots[-1]) / v_knots[-1])
        k = int(np.searchsorted(s_knots, s_m, side="left")) - 1
        if k < 0:
            return 0.0
        slope = (v_knots[k + 1] - v_knots[k]) / (t_knots[k + 1] - t_knots[k])
        ds = s_m - s_knots[k]  # s = v t + slope t^2 / 2 solved for its first root, stable for any slope
        return float(t_knots[k] + 2 * ds / (v_knots[k] + np.sqrt(v_knots[k] ** 2 + 2 * slope * ds)))

    def _spins(self) -> list[_TimedSpin]:
        """Where and when each spin happens, in the order driven."""
        spins, spun_s = [], 0.0
        for seg, at_m in zip(self.segments, self._bounds()):
            if isinstance(seg, Spin):
                spins.append(_TimedSpin(at_m, self._moving_time_at(at_m) + spun_s, seg.duration_s, seg.angle_deg))
                spun_s += seg.duration_s
        return spins

    def _bounds(self) -> np.ndarray:
        """Arc length [m] at the start of each segment, then at the end of the path."""
        return np.cumsum([0.0] + [seg.length_m for seg in self.segments])

    def pose_at_distance(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Arc length s [m] -> (xyz (N,3) m, yaw (N,) deg) along the path."""
        s = np.asarray(s, dtype=np.float64)
        if np.any(s < -1e-9) or np.any(s > self.length_m + 1e-6):
            raise ConfigError(f"the drive covers {np.max(s):.1f} m but the path is only {self.length_m:.1f} m long")
        starts = [(np.asarray(self.start_xy, dtype=np.float64), np.radians(self.start_yaw_deg))]
        for seg in self.segments:
            xy, heading = starts[-1]
            starts.append(_advance(seg, xy, heading, seg.length_m))
        bounds = self._bounds()
        index = np.clip(np.searchsorted(bounds, s, side="right") - 1, 0, len(self.segments) - 1)
        xy = np.zeros((len(s), 2))
        heading = np.zeros(len(s))
        for k, seg in enumerate(self.segments):
            mask = index == k
            if mask.any():
                xy[mask], heading[mask] = _advance(seg, *starts[k], s[mask] - bounds[k])
        xyz = np.column_stack([xy, np.full(len(s), self.height_m)])
        return xyz, np.degrees(heading)


class _TimedSpin(NamedTuple):
    """A spin of a drive: at arc length at_m [m], from start_s [s from the drive's start] for duration_s [s],
    turning by angle_deg [deg]."""

    at_m: float
    start_s: float
    duration_s: float
    angle_deg: float


def _advance(seg, xy, heading, ds):
    """Pose after driving ds [m] along one segment from (xy, heading rad); a spin's pose is the one after it."""
    ds = np.asarray(ds, dtype=np.float64)
    if isinstance(seg, Spin):
        return np.broadcast_to(xy, ds.shape + (2,)), heading + np.radians(seg.angle_deg) + 0.0 * ds
    if isinstance(seg, Straight):
        direction = np.array([np.cos(heading), np.sin(heading)])
        return xy + np.multiply.outer(ds, direction), heading + 0.0 * ds
    sign = np.sign(seg.angle_deg)
    turned = sign * ds / seg.radius_m
    centre = xy + seg.radius_m * sign * np.array([-np.sin(heading), np.cos(heading)])
    phi = heading + turned
    end = centre + seg.radius_m * sign * np.stack([np.sin(phi), -np.cos(phi)], axis=-1)
    return end, phi
