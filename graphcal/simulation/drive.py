"""Trajectory builders: a path (straights and arcs) driven with a speed profile.

Local frame x east, y north, z up [m]; yaw counter-clockwise from x [deg]. The body frame is
x forward, y left, z up; the vehicle drives on flat ground (roll = pitch = 0).
"""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

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


Segment = Annotated[Straight | Arc, Field(discriminator="kind")]


def straight(length_m: float) -> list:
    return [Straight(length_m=length_m)]


def turn(radius_m: float, angle_deg: float) -> list:
    return [Arc(radius_m=radius_m, angle_deg=angle_deg)]


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
        """Arc length driven [m] after elapsed_s >= 0 seconds (exact for piecewise-linear speed;
        the last speed holds after the last knot)."""
        elapsed_s = np.asarray(elapsed_s, dtype=np.float64)
        t_knots = np.array([t for t, _ in self.speed_knots] + [max(self.speed_knots[-1][0], elapsed_s.max()) + 1.0])
        v_knots = np.array([v for _, v in self.speed_knots] + [self.speed_knots[-1][1]])
        s_knots = np.r_[0.0, np.cumsum(np.diff(t_knots) * (v_knots[1:] + v_knots[:-1]) / 2)]
        k = np.clip(np.searchsorted(t_knots, elapsed_s, side="right") - 1, 0, len(t_knots) - 2)
        dt = elapsed_s - t_knots[k]
        slope = (v_knots[k + 1] - v_knots[k]) / (t_knots[k + 1] - t_knots[k])
        return s_knots[k] + v_knots[k] * dt + 0.5 * slope * dt * dt

    def pose_at_distance(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Arc length s [m] -> (xyz (N,3) m, yaw (N,) deg) along the path."""
        s = np.asarray(s, dtype=np.float64)
        if np.any(s < -1e-9) or np.any(s > self.length_m + 1e-6):
            raise ConfigError(f"the drive covers {np.max(s):.1f} m but the path is only {self.length_m:.1f} m long")
        starts = [(np.asarray(self.start_xy, dtype=np.float64), np.radians(self.start_yaw_deg))]
        for seg in self.segments:
            xy, heading = starts[-1]
            starts.append(_advance(seg, xy, heading, seg.length_m))
        bounds = np.cumsum([0.0] + [seg.length_m for seg in self.segments])
        index = np.clip(np.searchsorted(bounds, s, side="right") - 1, 0, len(self.segments) - 1)
        xy = np.zeros((len(s), 2))
        heading = np.zeros(len(s))
        for k, seg in enumerate(self.segments):
            mask = index == k
            if mask.any():
                xy[mask], heading[mask] = _advance(seg, *starts[k], s[mask] - bounds[k])
        xyz = np.column_stack([xy, np.full(len(s), self.height_m)])
        return xyz, np.degrees(heading)


def _advance(seg, xy, heading, ds):
    """Pose after driving ds [m] along one segment from (xy, heading rad)."""
    ds = np.asarray(ds, dtype=np.float64)
    if isinstance(seg, Straight):
        direction = np.array([np.cos(heading), np.sin(heading)])
        return xy + np.multiply.outer(ds, direction), heading + 0.0 * ds
    sign = np.sign(seg.angle_deg)
    turned = sign * ds / seg.radius_m
    centre = xy + seg.radius_m * sign * np.array([-np.sin(heading), np.cos(heading)])
    phi = heading + turned
    end = centre + seg.radius_m * sign * np.stack([np.sin(phi), -np.cos(phi)], axis=-1)
    return end, phi
