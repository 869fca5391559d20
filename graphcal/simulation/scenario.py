"""Scenario: everything the simulator needs, validated (pydantic), with defaults that work."""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator
from pyproj import CRS
from pyproj.exceptions import CRSError

from graphcal.simulation.effects import build_effects
from graphcal.recording.sensor import CATALOG
from graphcal.simulation.drive import Drive
from graphcal.simulation.scene import Markings, SceneObject
from graphcal.simulation.traffic import DistrictTrafficSpec, TrafficSpec

_FROZEN = ConfigDict(frozen=True, extra="forbid")


class IntrinsicErrors(BaseModel):
    """True per-fibre offsets from the nominal model, drawn per fibre (reference fibre: zero).

    Each offset type has a bound (|value| <= bound) and an RMS over the non-reference fibres;
    rms=None draws uniformly in [-bound, bound]. Units: m, deg, deg, m.
    """

    model_config = _FROZEN
    range_m: float = Field(0.0, ge=0)
    azimuth_deg: float = Field(0.0, ge=0)
    elevation_deg: float = Field(0.0, ge=0)
    h_z_m: float = Field(0.0, ge=0)
    rms: tuple[float, float, float, float] | None = Field(
        None, description="exact RMS (m, deg, deg, m) of the drawn offsets, each <= its bound")

    @model_validator(mode="after")
    def _rms_within_bounds(self) -> IntrinsicErrors:
        if self.rms is not None and any(r > b + 1e-12 for r, b in zip(self.rms, self.bounds)):
            raise ValueError("intrinsic_errors.rms must not exceed the bounds")
        return self

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        return (self.range_m, self.azimuth_deg, self.elevation_deg, self.h_z_m)


class InsErrors(BaseModel):
    """How the recorded GNSS/INS trajectory departs from the truth.

    Besides white noise and a piecewise-linear error, the drift of a GNSS-aided INS (ins_drift.py):
    a random walk of the position and of the heading, a slowly wandering position bias (first-order
    Gauss-Markov) and GNSS-like jumps (a position step at Poisson-distributed times, kept until the
    next). All off by default; every draw comes from the scenario's seed.
    """

    model_config = _FROZEN
    rate_hz: float = Field(100.0, gt=0, le=1000)
    position_noise_m: float = Field(0.0, ge=0, description="white noise per pose, each axis")
    attitude_noise_deg: float = Field(0.0, ge=0, description="white noise per pose, each angle")
    piecewise_error_m: float = Field(0.0, ge=0, description="RMS norm of a piecewise-linear position error")
    piecewise_interval_s: float = Field(1.0, gt=0)
    position_walk_m_sqrt_s: float = Field(0.0, ge=0, description="position random walk, each axis: "
                                                                 "sigma after t seconds = value x sqrt(t) [m/sqrt(s)]")
    heading_walk_deg_sqrt_s: float = Field(0.0, ge=0, description="heading (yaw) random walk [deg/sqrt(s)]")
    position_bias_m: float = Field(0.0, ge=0, description="slow position bias, stationary sigma each axis [m]")
    bias_correlation_s: float = Field(60.0, gt=0, description="correlation time of the slow bias [s]")
    jump_rate_hz: float = Field(0.0, ge=0, description="mean number of GNSS-like position jumps per second")
    jump_m: float = Field(0.0, ge=0, description="sigma of each jump's step, each axis [m]")


class OdometrySpec(BaseModel):
    """Wheel odometry (and an optional gyro) written to odometry.csv from the true motion.

    The body origin is the midpoint of the odometry axle. Wheel angles are the true wheel
    paths divided by the TRUE radius, wheel_radius_m * (1 + wheel_radius_error); recording.yaml
    gets the nominal wheel_radius_m. Noise is drawn from the scenario's seed.
    """

    model_config = _FROZEN
    rate_hz: float = Field(100.0, gt=0, le=1000)
    wheel_radius_m: float = Field(0.31, gt=0, description="nominal radius, written to recording.yaml [m]")
    track_m: float = Field(1.60, gt=0, description="distance between the left and right wheels [m]")
    wheel_radius_error: float = Field(0.0, gt=-0.5, lt=0.5, description="true radius = nominal x (1 + error)")
    wheel_noise_rad: float = Field(0.0, ge=0, description="white noise on each wheel's angle increment per sample")
    gyro: bool = Field(False, description="write a yaw_rate_rad_s column")
    gyro_noise_rad_s: float = Field(0.0, ge=0, description="white noise on each yaw-rate sample")


# seed 002's car: distance from the ABS wheel sensors, yaw rate from the ESP gyro (noiseless here)
SEED_002_ODOMETRY = OdometrySpec(gyro=True)


class ExtrinsicSpec(BaseModel):
    """Nominal lidar -> body pose (written to extrinsic.yaml) and the true one's departure from it."""

    model_config = _FROZEN
    lever_arm_m: tuple[float, float, float] = (0.8, 0.0, 1.9)
    boresight_deg: tuple[float, float, float] = (0.0, 0.0, 90.0)
    error_lever_arm_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    error_boresight_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)


class Scenario(BaseModel):
    """A simulated drive. Times in s, lengths in m, angles in deg; local frame x east, y north."""

    model_config = _FROZEN
    name: str
    sensor_model: str = "HDL-32E"
    rotation_hz: float = Field(10.0, gt=0, le=30)
    duration_s: float = Field(gt=0.3, description="span of the trajectory; the lidar records inside it")
    start_time_s: float = Field(1000.0, description="time of the first pose (same clock as the lidar)")
    size: float = Field(1.0, gt=0, le=1, description="fraction of firings kept (1 = the sensor's full rate)")
    seed: int = 0
    scene: list[SceneObject]
    markings: Markings | None = Field(None, description="painted patches on the static surfaces "
                                                        "(None: each surface of one reflectivity)")
    drive: Drive
    traffic: TrafficSpec | DistrictTrafficSpec | None = Field(
        None, description="moving vehicles and pedestrians, on a straight street or a grid district (None: none)")
    extrinsic: ExtrinsicSpec = ExtrinsicSpec()
    intrinsic_errors: IntrinsicErrors = IntrinsicErrors()
    range_noise_m: float = Field(0.0, ge=0)
    min_range_m: float = Field(1.0, ge=0)
    max_range_m: float = Field(100.0, gt=0)
    ins: InsErrors = InsErrors()
    odometry: OdometrySpec | None = Field(None, description="wheel odometry written to odometry.csv (None: none)")
    effects: dict[str, dict | bool] = Field(default_factory=dict,
                                            description="{name: params}; intra_sweep_motion is on unless False")
    crs: str = "EPSG:32631"
    origin_m: tuple[float, float, float] = Field((448000.0, 5411000.0, 50.0),
                                                 description="grid coordinates of the local origin")
    trajectory_format: str = Field("projected", pattern="^(projected|geodetic)$")
    truth_rate_hz: float = Field(200.0, gt=0)

    @field_validator("sensor_model")
    @classmethod
    def _known_sensor(cls, value: str) -> str:
        if value not in CATALOG:
            raise ValueError(f"unknown sensor {value!r}; known: {', '.join(CATALOG)}")
        return value

    @field_validator("crs")
    @classmethod
    def _projected_crs(cls, value: str) -> str:
        try:
            crs = CRS.from_user_input(value)
        except CRSError:
            raise ValueError(f"unknown CRS {value!r}; give a projected CRS such as EPSG:32631") from None
        if not crs.is_projected:
            raise ValueError(f"CRS {value!r} is not projected; give one such as EPSG:32631")
        return value

    @field_validator("effects")
    @classmethod
    def _known_effects(cls, value: dict) -> dict:
        build_effects(value)
        return value


def draw_offsets(errors: IntrinsicErrors, n_fibres: int, reference: int, rng: np.random.Generator) -> np.ndarray:
    """(n_fibres, 4) true offsets in (m, rad, rad, m); the reference fibre stays at zero."""
    others = np.array([i for i in range(n_fibres) if i != reference])
    offsets = np.zeros((n_fibres, 4))
    for k, bound in enumerate(errors.bounds):
        if bound == 0:
            continue
        if errors.rms is None:
            values = rng.uniform(-bound, bound, len(others))
        else:
            # squared magnitudes with mean rms^2 exactly, each within [0, bound^2], random signs
            u = rng.uniform(0, 1, len(others))
            spread = min(errors.rms[k] ** 2, bound ** 2 - errors.rms[k] ** 2)
            centred = (u - u.mean()) / max(np.abs(u - u.mean()).max(), 1e-12)
            values = np.sqrt(errors.rms[k] ** 2 + spread * centred) * rng.choice([-1.0, 1.0], len(others))
        offsets[others, k] = values
    offsets[:, 1:3] = np.radians(offsets[:, 1:3])
    return offsets
