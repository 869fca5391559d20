"""Registry of physical effects beyond the nominal model of eq. 4.2 + extrinsic + trajectory.

Each effect is a named, documented, switchable component with validated parameters
(intra_sweep_motion is on unless switched off with False). The
simulator applies the switched-on effects through the hooks below (identity by default); the
mismatch finder reasons about the same names (RECORDING.md, diagnosis.json `effect` names).

Hooks, in the order the simulator calls them (once for the head, then for every return):
  spin_hz(rotation_hz)               true spin rate of the head for the nominal one [Hz]
  factory_terms(factory, fibre)      true per-fibre factory terms for the nominal ones
  pose_time(t_pose, t_fire, t_rev)   time at which the sensor pose is taken [s]
  beam_azimuth(encoder_rad)          true beam azimuth for an encoder reading [rad]
  measured_range(range_m, cos_inc)   raw range reported for an ideal raw range [m]
  recorded_time(t_rec, t_fire, t_rev) time stamped on the return [s]
  max_stamp_shift_s()                the most it moves a stamp off the firing time [s]
and once for the recorded INS trajectory:
  ins_rpy(elapsed_s, rpy_deg)        attitude written to trajectory.csv [deg]
  ins_position(elapsed_s, xyz_m)     position written to trajectory.csv [m, local frame]

The extrinsic's lever-arm error is not an effect here: it is ExtrinsicSpec.error_lever_arm_m (the
true extrinsic), and the mismatch finder's `lever_arm` candidate stands for it when the model holds
the extrinsic fixed.
"""

from __future__ import annotations

from dataclasses import replace
from typing import ClassVar, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from factors.spherical import FactoryTerms
from graphcal.common.errors import ConfigError

REGISTRY: dict[str, type[Effect]] = {}


def register(cls: type[Effect]) -> type[Effect]:
    REGISTRY[cls.name] = cls
    return cls


class Effect(BaseModel):
    """Base class: one sentence of physics, the unit of its headline magnitude, and hooks."""

    model_config = ConfigDict(frozen=True, extra="forbid")
    name: ClassVar[str]
    physics: ClassVar[str]
    unit: ClassVar[str]

    def magnitude(self) -> float:
        """Headline magnitude in `unit` (as reported in diagnosis.json)."""
        raise NotImplementedError

    def spin_hz(self, rotation_hz: float) -> float:
        return rotation_hz

    def factory_terms(self, factory: FactoryTerms, fibre: np.ndarray) -> FactoryTerms:
        return factory

    def pose_time(self, t_pose, t_fire, t_rev):
        return t_pose

    def beam_azimuth(self, encoder_rad):
        return encoder_rad

    def measured_range(self, range_m, cos_incidence):
        return range_m

    def recorded_time(self, t_rec, t_fire, t_rev):
        return t_rec

    def max_stamp_shift_s(self) -> float:
        """Largest |recorded - firing| time this effect adds [s] (the recording keeps clear of
        the trajectory's ends by this much)."""
        return 0.0

    def ins_rpy(self, elapsed_s, rpy_deg):
        return rpy_deg

    def ins_position(self, elapsed_s, xyz_m):
        return xyz_m


@register
class IntraSweepMotion(Effect):
    """On by default. Without it every revolution is cast from the pose at its start (a frozen
    sweep). stamp='revolution' stamps each return with its revolution's start time instead
    of its firing time (the left-out physics a model assuming per-return times misses)."""

    name: ClassVar[str] = "intra_sweep_motion"
    physics: ClassVar[str] = "the vehicle moves while the head spins, so each return is taken from its own pose"
    unit: ClassVar[str] = "revolution"
    stamp: Literal["firing", "revolution"] = "firing"

    def magnitude(self) -> float:
        """How far (in revolutions, at most) a stamp precedes its firing: 0 or 1."""
        return 0.0 if self.stamp == "firing" else 1.0

    def pose_time(self, t_pose, t_fire, t_rev):
        return t_fire

    def recorded_time(self, t_rec, t_fire, t_rev):
        return t_rev if self.stamp == "revolution" else t_rec


@register
class TimeOffset(Effect):
    """Lidar clock ahead of the INS clock: stamped time = true time + offset_s."""

    name: ClassVar[str] = "time_offset"
    physics: ClassVar[str] = "the lidar timestamps are offset from the INS clock by a constant latency"
    unit: ClassVar[str] = "s"
    offset_s: float

    def magnitude(self) -> float:
        return self.offset_s

    def recorded_time(self, t_rec, t_fire, t_rev):
        return t_rec + self.offset_s

    def max_stamp_shift_s(self) -> float:
        return abs(self.offset_s)


@register
class RangeScale(Effect):
    """Measured range = (1 + scale) x true range (scale = measured/true - 1)."""

    name: ClassVar[str] = "range_scale"
    physics: ClassVar[str] = "the time-of-flight clock runs fast or slow, scaling every range"
    unit: ClassVar[str] = "1"
    scale: float

    def magnitude(self) -> float:
        return self.scale

    def measured_range(self, range_m, cos_incidence):
        return range_m * (1.0 + self.scale)


@register
class IncidenceRangeBias(Effect):
    """Range bias growing with incidence: + bias_m (1 - cos alpha), bias_m at grazing (90 deg)."""

    name: ClassVar[str] = "incidence_range_bias"
    physics: ClassVar[str] = "the footprint spreads on oblique surfaces and the pulse detector fires late"
    unit: ClassVar[str] = "m"
    bias_m: float

    def magnitude(self) -> float:
        return self.bias_m

    def measured_range(self, range_m, cos_incidence):
        return range_m + self.bias_m * (1.0 - cos_incidence)


@register
class AzimuthEccentricity(Effect):
    """Encoder disc off-centre: true azimuth = encoder + amplitude sin(encoder + phase)."""

    name: ClassVar[str] = "azimuth_eccentricity"
    physics: ClassVar[str] = "the encoder disc is off the spin axis, so the azimuth error is a sinusoid of azimuth"
    unit: ClassVar[str] = "deg"
    amplitude_deg: float
    phase_deg: float = 0.0

    def magnitude(self) -> float:
        return self.amplitude_deg

    def beam_azimuth(self, encoder_rad):
        return encoder_rad + np.radians(self.amplitude_deg) * np.sin(encoder_rad + np.radians(self.phase_deg))


def _add_yaw(rpy_deg, yaw_deg):
    out = np.array(rpy_deg, dtype=np.float64, copy=True)
    out[:, 2] += yaw_deg
    return out


@register
class HeadingBias(Effect):
    """INS yaw written = true yaw + bias_deg."""

    name: ClassVar[str] = "heading_bias"
    physics: ClassVar[str] = "the INS heading is off by a constant angle"
    unit: ClassVar[str] = "deg"
    bias_deg: float

    def magnitude(self) -> float:
        return self.bias_deg

    def ins_rpy(self, elapsed_s, rpy_deg):
        return _add_yaw(rpy_deg, self.bias_deg)


@register
class HeadingDrift(Effect):
    """INS yaw written = true yaw + rate_deg_s x (time since the first pose)."""

    name: ClassVar[str] = "heading_drift"
    physics: ClassVar[str] = "the INS heading error grows linearly with time"
    unit: ClassVar[str] = "deg/s"
    rate_deg_s: float

    def magnitude(self) -> float:
        return self.rate_deg_s

    def ins_rpy(self, elapsed_s, rpy_deg):
        return _add_yaw(rpy_deg, self.rate_deg_s * np.asarray(elapsed_s))


@register
class ProjectionScale(Effect):
    """Recorded INS positions = first position + (1 + scale) x (true displacement): the grid of a
    map projection is larger than the ground by its scale factor k = 1 + scale, and the lidar's
    metric vectors are placed in it unscaled (graphcal ignores k, docs/concepts.md "Frames and names")."""

    name: ClassVar[str] = "projection_scale"
    physics: ClassVar[str] = ("the trajectory is in a map grid whose scale factor differs from 1, while the lidar "
                              "measures true metres")
    unit: ClassVar[str] = "1"
    scale: float

    def magnitude(self) -> float:
        return self.scale

    def ins_position(self, elapsed_s, xyz_m):
        xyz_m = np.asarray(xyz_m, dtype=np.float64)
        return xyz_m[0] + (1.0 + self.scale) * (xyz_m - xyz_m[0])


@register
class SpinRate(Effect):
    """The head spins at rotation_hz x (1 + error) while the time of each return inside its
    revolution is derived from its azimuth at the nominal rate (as importers without per-firing
    times do): stamp = revolution start + azimuth / (2 pi nominal rate)."""

    name: ClassVar[str] = "spin_rate"
    physics: ClassVar[str] = ("the head spins faster or slower than its nominal rate, and times derived from the "
                              "azimuth at the nominal rate drift within each revolution")
    unit: ClassVar[str] = "1"
    error: float = Field(gt=-0.5, lt=0.5)

    def magnitude(self) -> float:
        return self.error

    def spin_hz(self, rotation_hz: float) -> float:
        return rotation_hz * (1.0 + self.error)

    def recorded_time(self, t_rec, t_fire, t_rev):
        # t_rev + azimuth / (2 pi f_nominal) = t_rev + (t_fire - t_rev) f_true / f_nominal
        return t_rec + self.error * (t_fire - t_rev)

    def max_stamp_shift_s(self) -> float:
        return abs(self.error)  # x one revolution, which lasts less than 1 s


@register
class FibreHorizontalOffset(Effect):
    """Each laser sits beside the spin axis (HDL-64E model, H_i of eq. 4.2's factory terms): true
    horizontal offset = nominal + offset_m for even fibres, - offset_m for odd ones (the two sides of
    the head); sensor.yaml keeps the nominal values."""

    name: ClassVar[str] = "fibre_horizontal_offset"
    physics: ClassVar[str] = ("each laser is offset sideways from the spin axis, shifting its returns across the "
                              "beam by a constant length")
    unit: ClassVar[str] = "m"
    offset_m: float

    def magnitude(self) -> float:
        return abs(self.offset_m)

    def factory_terms(self, factory: FactoryTerms, fibre: np.ndarray) -> FactoryTerms:
        side = np.where(np.asarray(fibre) % 2 == 0, 1.0, -1.0)
        return replace(factory, horizontal_offset_m=factory.horizontal_offset_m + self.offset_m * side)


ON_BY_DEFAULT = ("intra_sweep_motion",)


def build_effects(spec: dict[str, dict | bool] | None) -> list[Effect]:
    """{'name': {params}} -> validated effects, in registry order (the order hooks compose).

    Effects of ON_BY_DEFAULT are added unless given as False; {'name': False} switches off.
    """
    spec = {**{name: {} for name in ON_BY_DEFAULT}, **(spec or {})}
    spec = {name: params for name, params in spec.items() if params is not False}
    unknown = sorted(set(spec) - set(REGISTRY))
    if unknown:
        raise ConfigError(f"unknown effect(s) {unknown}; known: {', '.join(REGISTRY)}")
    effects = []
    for name, cls in REGISTRY.items():
        if name in spec:
            try:
                params = spec[name]
                if params is not True and not isinstance(params, dict):
                    raise ConfigError(f"effect '{name}': {params!r} is neither parameters nor True/False")
                effects.append(cls(**(params if isinstance(params, dict) else {})))
            except ValidationError as error:
                raise ConfigError(f"effect '{name}': {error.errors()[0]['loc']} {error.errors()[0]['msg']}") from None
    return effects


def describe(effects: list[Effect]) -> dict:
    """What effects.yaml records: each switched-on effect with its parameters and magnitude."""
    return {e.name: {**e.model_dump(), "magnitude": float(e.magnitude()), "unit": e.unit, "physics": e.physics}
            for e in effects}
