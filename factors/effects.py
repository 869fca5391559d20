"""The physical effects beyond the nominal model of eq. 4.2 + extrinsic + trajectory: one definition each.

An effect is a pydantic model whose fields are its simulation parameters, with

- its name (effects.yaml, diagnosis.json, calibration.yaml), the unit of its headline magnitude and one
  sentence of physics (the diagnosis's statements quote it);
- its simulation hooks, called by the simulator (identity by default), in this order, once for the head and
  then for every return:
    spin_hz(rotation_hz)               true spin rate of the head for the nominal one [Hz]
    factory_terms(factory, fibre)      true per-fibre factory terms for the nominal ones
    pose_time(t_pose, t_fire, t_rev)   time at which the sensor pose is taken [s]
    beam_azimuth(encoder_rad)          true beam azimuth for an encoder reading [rad]
    beam_elevation(encoder_rad)        change of the beam's elevation at an encoder reading [rad]
    measured_range(range_m, cos_inc, intensity, elapsed_s)  raw range reported for an ideal raw range [m]
    recorded_time(t_rec, t_fire, t_rev, fibre)  time stamped on the return [s]
    max_stamp_shift_s()                the most it moves a stamp off the firing time [s]
  and once for the recorded INS trajectory:
    ins_rpy(elapsed_s, rpy_deg)        attitude written to trajectory.csv [deg]
    ins_position(elapsed_s, xyz_m)     position written to trajectory.csv [m, local frame]
- its candidate basis for the mismatch finder: dim(n_fibres) parameters theta that move the channels of
  factors.channels linearly (basis(context)), its residual signature in a sentence, and the headline
  magnitude of a theta in `unit` (magnitude_of). The basis is the linearisation of the simulation hooks
  about zero, with theta in the candidate's own parameters (`parameters` says which).

`lever_arm` is a candidate only: the simulator's lever-arm error is the scenario's extrinsic error
(ExtrinsicSpec.error_lever_arm_m), and the candidate stands for it when a model holds the extrinsic fixed.
"""

from __future__ import annotations

from dataclasses import replace
from typing import ClassVar, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from factors.channels import Basis, Context
from factors.discrepancy import Discrepancy, is_discrepancy
from factors.spherical import FactoryTerms

REGISTRY: dict[str, type[Effect]] = {}


def register(cls: type[Effect]) -> type[Effect]:
    REGISTRY[cls.name] = cls
    return cls


def _column(values: np.ndarray) -> np.ndarray:
    return np.asarray(values, dtype=np.float64)[:, None]


def _ones(context: Context) -> np.ndarray:
    return np.ones((len(context.fibre), 1))


class Effect(BaseModel):
    """Base class: name, unit, physics, signature and the candidate's parameters in ClassVars; the
    simulation hooks (identity here) and the candidate basis (one scalar parameter by default)."""

    model_config = ConfigDict(frozen=True, extra="forbid")
    name: ClassVar[str]
    unit: ClassVar[str]
    physics: ClassVar[str]
    signature: ClassVar[str]
    parameters: ClassVar[str]
    simulated: ClassVar[bool] = True

    def magnitude(self) -> float:
        """Headline magnitude of these simulation parameters, in `unit` (as diagnosis.json reports it)."""
        raise NotImplementedError

    def spin_hz(self, rotation_hz: float) -> float:
        return rotation_hz

    def factory_terms(self, factory: FactoryTerms, fibre: np.ndarray) -> FactoryTerms:
        return factory

    def pose_time(self, t_pose, t_fire, t_rev):
        return t_pose

    def beam_azimuth(self, encoder_rad):
        return encoder_rad

    def beam_elevation(self, encoder_rad):
        return np.zeros_like(encoder_rad)

    def measured_range(self, range_m, cos_incidence, intensity, elapsed_s):
        return range_m

    def recorded_time(self, t_rec, t_fire, t_rev, fibre):
        return t_rec

    def max_stamp_shift_s(self) -> float:
        """Largest |recorded - firing| time this effect adds [s] (the recording keeps clear of
        the trajectory's ends by this much)."""
        return 0.0

    def ins_rpy(self, elapsed_s, rpy_deg):
        return rpy_deg

    def ins_position(self, elapsed_s, xyz_m):
        return xyz_m

    @classmethod
    def dim(cls, n_fibres: int) -> int:
        """Number of candidate parameters for a head of n_fibres."""
        return 1

    @classmethod
    def basis(cls, context: Context) -> Basis:
        """The candidate's linear map from its parameters to the channels of the context's returns."""
        raise NotImplementedError

    @classmethod
    def magnitude_of(cls, theta: np.ndarray) -> float:
        """Headline magnitude, in `unit`, of candidate parameters theta."""
        return float(theta[0])


@register
class IntraSweepMotion(Effect):
    """On by default in the simulator: each return is cast from the pose at its own firing time (without
    it every revolution is cast from the pose at its start, a frozen sweep). stamp='revolution' stamps
    each return with its revolution's start time instead of its firing time."""

    name: ClassVar[str] = "intra_sweep_motion"
    unit: ClassVar[str] = "revolution"
    physics: ClassVar[str] = ("the vehicle moves while the head spins, and returns stamped with their revolution's "
                              "start time instead of their own firing time miss that motion")
    signature: ClassVar[str] = ("time error growing linearly over the revolution (from 0 to one period), a step at "
                                "the cut; displacement proportional to speed and, in turns, to yaw rate x range")
    parameters: ClassVar[str] = "fraction of the time within the revolution missing from each stamp (1 = revolution stamps)"
    stamp: Literal["firing", "revolution"] = "firing"

    def magnitude(self) -> float:
        """How far (in revolutions, at most) a stamp precedes its firing: 0 or 1."""
        return 0.0 if self.stamp == "firing" else 1.0

    def pose_time(self, t_pose, t_fire, t_rev):
        return t_fire

    def recorded_time(self, t_rec, t_fire, t_rev, fibre):
        return t_rev if self.stamp == "revolution" else t_rec

    @classmethod
    def basis(cls, context: Context) -> Basis:
        return Basis(1, time=_column(context.sweep_s))


@register
class TimeOffset(Effect):
    """Lidar clock ahead of the INS clock: stamped time = true time + offset_s."""

    name: ClassVar[str] = "time_offset"
    unit: ClassVar[str] = "s"
    physics: ClassVar[str] = "the lidar clock is offset from the INS clock by a constant latency"
    signature: ClassVar[str] = ("displacement v dt along the track (sign flips with the driving direction) and "
                                "omega x r dt in turns")
    parameters: ClassVar[str] = "stamped minus true time [s]"
    offset_s: float

    def magnitude(self) -> float:
        return self.offset_s

    def recorded_time(self, t_rec, t_fire, t_rev, fibre):
        return t_rec + self.offset_s

    def max_stamp_shift_s(self) -> float:
        return abs(self.offset_s)

    @classmethod
    def basis(cls, context: Context) -> Basis:
        return Basis(1, time=-_ones(context))


@register
class RangeScale(Effect):
    """Measured range = (1 + scale) x true range (scale = measured/true - 1)."""

    name: ClassVar[str] = "range_scale"
    unit: ClassVar[str] = "1"
    physics: ClassVar[str] = "the time-of-flight clock runs fast or slow, scaling every range"
    signature: ClassVar[str] = "range error proportional to range, the same for every fibre"
    parameters: ClassVar[str] = "measured / true range - 1"
    scale: float

    def magnitude(self) -> float:
        return self.scale

    def measured_range(self, range_m, cos_incidence, intensity, elapsed_s):
        return range_m * (1.0 + self.scale)

    @classmethod
    def basis(cls, context: Context) -> Basis:
        return Basis(1, range=-_column(context.range_m))


@register
class RangeOffset(Effect):
    """Measured range = true range + offset_m on every fibre, the reference fibre's too. The per-fibre range
    offsets take such an offset on every fibre but the reference, whose offsets are fixed (the gauge), so the model
    cannot hold it without this parameter: a range curve's constant (a drift's mean over the drive) has nowhere
    else to go."""

    name: ClassVar[str] = "range_offset"
    unit: ClassVar[str] = "m"
    physics: ClassVar[str] = "every fibre's range, the reference fibre's too, is off by the same amount"
    signature: ClassVar[str] = "range error common to every fibre, the reference fibre's too"
    parameters: ClassVar[str] = "range offset common to every fibre [m]"
    offset_m: float

    def magnitude(self) -> float:
        return self.offset_m

    def measured_range(self, range_m, cos_incidence, intensity, elapsed_s):
        return range_m + self.offset_m

    @classmethod
    def basis(cls, context: Context) -> Basis:
        return Basis(1, range=-_ones(context))


@register
class IncidenceRangeBias(Effect):
    """Range bias growing with incidence: + bias_m (1 - cos alpha), bias_m at grazing (90 deg)."""

    name: ClassVar[str] = "incidence_range_bias"
    unit: ClassVar[str] = "m"
    physics: ClassVar[str] = "the footprint spreads on oblique surfaces and the pulse detector fires late"
    signature: ClassVar[str] = "range error growing with the incidence angle, largest on grazing road returns"
    parameters: ClassVar[str] = "range bias at grazing (90 deg) incidence [m]"
    bias_m: float

    def magnitude(self) -> float:
        return self.bias_m

    def measured_range(self, range_m, cos_incidence, intensity, elapsed_s):
        return range_m + self.bias_m * (1.0 - cos_incidence)

    @classmethod
    def basis(cls, context: Context) -> Basis:
        return Basis(1, range=-_column(1.0 - context.cos_incidence))


@register
class AzimuthEccentricity(Effect):
    """Encoder disc off-centre: true azimuth = encoder + amplitude sin(encoder + phase)."""

    name: ClassVar[str] = "azimuth_eccentricity"
    unit: ClassVar[str] = "deg"
    physics: ClassVar[str] = ("the encoder disc is off the spin axis, so the azimuth error is a sinusoid of "
                              "azimuth")
    signature: ClassVar[str] = ("azimuth error a sin(theta) + b cos(theta): a tangential displacement proportional "
                                "to range, sinusoidal over the azimuth")
    parameters: ClassVar[str] = "(A cos phase, A sin phase) [rad] of true azimuth = encoder + A sin(encoder + phase)"
    amplitude_deg: float
    phase_deg: float = 0.0

    def magnitude(self) -> float:
        return self.amplitude_deg

    def beam_azimuth(self, encoder_rad):
        return encoder_rad + np.radians(self.amplitude_deg) * np.sin(encoder_rad + np.radians(self.phase_deg))

    @classmethod
    def dim(cls, n_fibres: int) -> int:
        return 2

    @classmethod
    def basis(cls, context: Context) -> Basis:
        return Basis(2, azimuth=np.column_stack([np.sin(context.azimuth_rad), np.cos(context.azimuth_rad)]))

    @classmethod
    def magnitude_of(cls, theta: np.ndarray) -> float:
        return float(np.degrees(np.hypot(theta[0], theta[1])))


class _HeadingError(Effect):
    """An INS yaw error: the candidate turns each pose about world z by minus its value [rad]."""

    unit: ClassVar[str] = "deg"

    def yaw_deg(self, elapsed_s):
        raise NotImplementedError

    def ins_rpy(self, elapsed_s, rpy_deg):
        out = np.array(rpy_deg, dtype=np.float64, copy=True)
        out[:, 2] += self.yaw_deg(elapsed_s)
        return out

    @classmethod
    def magnitude_of(cls, theta: np.ndarray) -> float:
        return float(np.degrees(theta[0]))


@register
class HeadingBias(_HeadingError):
    """INS yaw written = true yaw + bias_deg."""

    name: ClassVar[str] = "heading_bias"
    physics: ClassVar[str] = "the INS heading is off by a constant angle"
    signature: ClassVar[str] = ("a rotation of every scan about the vehicle's vertical axis: tangential error "
                                "proportional to range")
    parameters: ClassVar[str] = "recorded minus true heading [rad]"
    bias_deg: float

    def magnitude(self) -> float:
        return self.bias_deg

    def yaw_deg(self, elapsed_s):
        return self.bias_deg

    @classmethod
    def basis(cls, context: Context) -> Basis:
        return Basis(1, heading=-_ones(context))


@register
class HeadingDrift(_HeadingError):
    """INS yaw written = true yaw + rate_deg_s x (time since the first pose)."""

    name: ClassVar[str] = "heading_drift"
    unit: ClassVar[str] = "deg/s"
    physics: ClassVar[str] = "the INS heading error grows linearly with time"
    signature: ClassVar[str] = ("a rotation about the vehicle's vertical axis growing with time: scans of one place "
                                "seen at different times disagree by range x rate x time")
    parameters: ClassVar[str] = "rate of recorded minus true heading [rad/s]"
    rate_deg_s: float

    def magnitude(self) -> float:
        return self.rate_deg_s

    def yaw_deg(self, elapsed_s):
        return self.rate_deg_s * np.asarray(elapsed_s)

    @classmethod
    def basis(cls, context: Context) -> Basis:
        return Basis(1, heading=-_column(context.elapsed_s))


@register
class LeverArm(Effect):
    """The lidar's position on the vehicle differs from the nominal lever arm. A candidate only: the
    simulator takes this error as the scenario's extrinsic error."""

    name: ClassVar[str] = "lever_arm"
    unit: ClassVar[str] = "m"
    physics: ClassVar[str] = "the lidar's position on the vehicle differs from the nominal lever arm"
    signature: ClassVar[str] = ("a constant offset in the body frame: opposite-direction passes disagree by twice "
                                "the offset")
    parameters: ClassVar[str] = "lever-arm error (x, y, z) [m, body frame]"
    simulated: ClassVar[bool] = False

    @classmethod
    def dim(cls, n_fibres: int) -> int:
        return 3

    @classmethod
    def basis(cls, context: Context) -> Basis:
        return Basis(3, body=np.broadcast_to(np.eye(3), (len(context.fibre), 3, 3)))

    @classmethod
    def magnitude_of(cls, theta: np.ndarray) -> float:
        return float(np.linalg.norm(theta))


@register
class ProjectionScale(Effect):
    """Recorded INS positions = first position + (1 + scale) x (true displacement): the grid of a
    map projection is larger than the ground by its scale factor k = 1 + scale, and the lidar's
    metric vectors are placed in it unscaled (graphcal ignores k)."""

    name: ClassVar[str] = "projection_scale"
    unit: ClassVar[str] = "1"
    physics: ClassVar[str] = ("the trajectory is in a map grid whose scale factor k differs from 1 while the lidar "
                              "measures true metres")
    signature: ClassVar[str] = ("position error proportional to the distance driven (like a range scale, but in "
                                "the trajectory)")
    parameters: ClassVar[str] = "k - 1 of the trajectory's grid against the lidar's metres"
    scale: float

    def magnitude(self) -> float:
        return self.scale

    def ins_position(self, elapsed_s, xyz_m):
        xyz_m = np.asarray(xyz_m, dtype=np.float64)
        return xyz_m[0] + (1.0 + self.scale) * (xyz_m - xyz_m[0])

    @classmethod
    def basis(cls, context: Context) -> Basis:
        return Basis(1, position=-np.asarray(context.X_nav, dtype=np.float64)[:, :, None])


@register
class SpinRate(Effect):
    """The head spins at rotation_hz x (1 + error) while the time of each return inside its
    revolution is derived from its azimuth at the nominal rate (as importers without per-firing
    times do): stamp = revolution start + azimuth / (2 pi nominal rate)."""

    name: ClassVar[str] = "spin_rate"
    unit: ClassVar[str] = "1"
    physics: ClassVar[str] = ("the head spins faster or slower than its nominal rate, and times derived from the "
                              "azimuth at the nominal rate drift within each revolution")
    signature: ClassVar[str] = "time error growing linearly with the azimuth from the cut, scaled by speed"
    parameters: ClassVar[str] = "relative spin-rate error (true / nominal - 1)"
    error: float = Field(gt=-0.5, lt=0.5)

    def magnitude(self) -> float:
        return self.error

    def spin_hz(self, rotation_hz: float) -> float:
        return rotation_hz * (1.0 + self.error)

    def recorded_time(self, t_rec, t_fire, t_rev, fibre):
        # t_rev + azimuth / (2 pi f_nominal) = t_rev + (t_fire - t_rev) f_true / f_nominal
        return t_rec + self.error * (t_fire - t_rev)

    def max_stamp_shift_s(self) -> float:
        return abs(self.error)  # x one revolution, which lasts less than 1 s

    @classmethod
    def basis(cls, context: Context) -> Basis:
        return Basis(1, time=-_column(context.sweep_s))


@register
class FibreHorizontalOffset(Effect):
    """Each laser sits beside the spin axis (HDL-64E model, H_i of eq. 4.2's factory terms): true
    horizontal offset = nominal + offset_m for even fibres, - offset_m for odd ones (the two sides of
    the head); sensor.yaml keeps the nominal values. As a candidate, one offset per fibre."""

    name: ClassVar[str] = "fibre_horizontal_offset"
    unit: ClassVar[str] = "m"
    physics: ClassVar[str] = ("each laser is offset sideways from the spin axis, shifting its returns across the "
                              "beam by a constant length")
    signature: ClassVar[str] = ("a constant sideways shift per fibre, independent of range (an azimuth offset's "
                                "grows with range)")
    parameters: ClassVar[str] = "per-fibre horizontal offset error [m]"
    offset_m: float

    def magnitude(self) -> float:
        return abs(self.offset_m)

    def factory_terms(self, factory: FactoryTerms, fibre: np.ndarray) -> FactoryTerms:
        side = np.where(np.asarray(fibre) % 2 == 0, 1.0, -1.0)
        return replace(factory, horizontal_offset_m=factory.horizontal_offset_m + self.offset_m * side)

    @classmethod
    def dim(cls, n_fibres: int) -> int:
        return n_fibres

    @classmethod
    def basis(cls, context: Context) -> Basis:
        one_hot = np.zeros((len(context.fibre), context.n_fibres))
        one_hot[np.arange(len(context.fibre)), context.fibre] = 1.0
        return Basis(context.n_fibres, horizontal=one_hot)

    @classmethod
    def magnitude_of(cls, theta: np.ndarray) -> float:
        return float(np.sqrt(np.mean(np.square(theta))))


class _SimulatedOnly(Effect):
    """An effect the simulator can inject but the mismatch finder has no candidate for: what a real head
    carries that nobody listed (the open-world diagnosis must find it with its generic discrepancies)."""

    signature: ClassVar[str] = "none given: the finder has no candidate for it"
    parameters: ClassVar[str] = "none: simulated only"

    @classmethod
    def basis(cls, context: Context) -> Basis:
        raise NotImplementedError(f"{cls.name} is simulated only: the mismatch finder has no candidate for it")


@register
class RangeWalk(_SimulatedOnly):
    """Weak returns read long: measured range + walk_m exp(-intensity / scale), intensity in 0-255."""

    name: ClassVar[str] = "range_walk"
    unit: ClassVar[str] = "m"
    physics: ClassVar[str] = "the detector's threshold fires later on weak returns, so they read long"
    walk_m: float
    scale: float = Field(40.0, gt=0)

    def magnitude(self) -> float:
        return self.walk_m

    def measured_range(self, range_m, cos_incidence, intensity, elapsed_s):
        return range_m + self.walk_m * np.exp(-np.asarray(intensity) / self.scale)


@register
class ThermalRangeDrift(_SimulatedOnly):
    """The range offset warms up: measured range + drift_m (1 - exp(-t / tau_s)), t since the recording began."""

    name: ClassVar[str] = "thermal_range_drift"
    unit: ClassVar[str] = "m"
    physics: ClassVar[str] = "the head warms after power-on and its range offset drifts"
    drift_m: float
    tau_s: float = Field(3.0, gt=0)

    def magnitude(self) -> float:
        return self.drift_m

    def measured_range(self, range_m, cos_incidence, intensity, elapsed_s):
        return range_m + self.drift_m * (1.0 - np.exp(-np.asarray(elapsed_s) / self.tau_s))


@register
class HeadWobble(_SimulatedOnly):
    """The spinning head nods twice a turn (an out-of-round bearing): every beam's elevation changes by
    amplitude_deg sin(2 encoder + phase). Once a turn would be a tilted spin axis, which the boresight is."""

    name: ClassVar[str] = "head_wobble"
    unit: ClassVar[str] = "deg"
    physics: ClassVar[str] = "the spinning head nods as it turns, moving every beam's elevation with the azimuth"
    amplitude_deg: float
    phase_deg: float = 0.0

    def magnitude(self) -> float:
        return self.amplitude_deg

    def beam_elevation(self, encoder_rad):
        return np.radians(self.amplitude_deg) * np.sin(2.0 * np.asarray(encoder_rad) + np.radians(self.phase_deg))


@register
class FiringDelay(_SimulatedOnly):
    """Each laser fires step_s after the one before it (by fibre id) while the driver stamps them all at once:
    stamp = firing time - step_s x fibre."""

    name: ClassVar[str] = "firing_delay"
    unit: ClassVar[str] = "s"
    physics: ClassVar[str] = "the lasers fire one after another while the driver stamps them as one firing"
    step_s: float = Field(ge=0, le=1e-3)

    def magnitude(self) -> float:
        return self.step_s

    def recorded_time(self, t_rec, t_fire, t_rev, fibre):
        return t_rec - self.step_s * np.asarray(fibre)

    def max_stamp_shift_s(self) -> float:
        return 128 * self.step_s  # the most fibres a head has


# every effect is a candidate of the mismatch finder, tried in this order (the clock's first, then the range's,
# the azimuth's, the INS's and the geometry's)
CANDIDATES: dict[str, type[Effect]] = {name: REGISTRY[name] for name in (
    "intra_sweep_motion", "time_offset", "spin_rate", "range_scale", "incidence_range_bias", "azimuth_eccentricity",
    "heading_bias", "heading_drift", "lever_arm", "projection_scale", "fibre_horizontal_offset")}
# a channel's constant, solved beside every discrepancy of its channel when that one is added (graphcal.diagnosis:
# the discrepancies' bases have no constant, and no ordinary parameter holds it): the range's is never tested on
# its own; the time's is the latency, also a candidate (a per-laser firing delay's mean over the fibres is one)
SOLVED_BESIDE: dict[str, type[Effect]] = {"range": REGISTRY["range_offset"], "time": REGISTRY["time_offset"]}
# every named effect the finder models: its candidates and the constants it solves beside a discrepancy
MODELLED: dict[str, type[Effect]] = CANDIDATES | {cls.name: cls for cls in SOLVED_BESIDE.values()}
SIMULATED: dict[str, type[Effect]] = {name: cls for name, cls in REGISTRY.items() if cls.simulated}


def candidate(name: str) -> type[Effect] | Discrepancy:
    """What the mismatch finder models under a name: a candidate or a constant it solves beside a discrepancy
    (MODELLED), or the generic discrepancy its spec names (factors.discrepancy)."""
    if name in MODELLED:
        return MODELLED[name]
    if is_discrepancy(name):
        return Discrepancy.parse(name)
    raise KeyError(f"no effect and no discrepancy is named {name!r}")
