"""Departures of a real head and INS from the contract's model (RECORDING.md), each written here from
its physics: what a mismatch finder must name on data it was not fitted to. Off by default.

Each departure is written to truth/effects.yaml under the name RECORDING.md gives it ("diagnosis.json"),
with its magnitude in the unit a diagnosis reports it in:

- range_scale [1]: the time-of-flight clock runs fast by this fraction, so the distance the head measures
  is the true one x (1 + range_scale), before the per-fibre range offset is taken off.
- incidence_range_bias [m at 90 deg incidence]: the footprint spreads on an oblique surface and the
  detector fires late; the measured distance is longer by bias_m (1 - cos incidence).
- azimuth_eccentricity [deg]: the encoder disc is mounted off the spin axis (its centre e from the axis,
  graduations at radius R), so the reading lags the head's true angle psi by A sin(psi + phase), A = e / R.
  The beam leaves along psi; the return carries the reading.
- time_offset [s]: a latency between the INS's clock and the lidar's stamps: every return is stamped
  latency_s after its laser fired (the lidar stamps when its packet is made, not when it fires).
- heading_drift [deg/s]: the INS's heading (yaw, counter-clockwise from the grid's east) drifts from the
  truth at a constant rate from its first pose.
- intra_sweep_motion [revolution]: the driver stamps every return with the time its revolution began
  (the encoder crossing the cut at azimuth 0), not its laser's firing time: a stamp misses up to a whole
  revolution (magnitude 1).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np


@dataclass(frozen=True)
class Departures:
    """What the recording departs from the contract's model by (zero: not at all). Units in the names."""

    range_scale: float = 0.0
    incidence_range_bias_m: float = 0.0
    eccentricity_deg: float = 0.0
    eccentricity_phase_deg: float = 0.0
    latency_s: float = 0.0
    heading_drift_deg_s: float = 0.0
    revolution_stamps: bool = False

    def __post_init__(self):
        if not -0.5 < self.range_scale < 0.5:
            raise ValueError(f"range_scale must be a small fraction, not {self.range_scale}")
        if not 0.0 <= self.eccentricity_deg < 5.0:
            raise ValueError(f"eccentricity_deg must be in [0, 5), not {self.eccentricity_deg}")

    def measured_distance(self, distance_m: np.ndarray, cos_incidence: np.ndarray) -> np.ndarray:
        """The distance [m] the head measures for a true distance along the beam, before its range offset."""
        return distance_m * (1.0 + self.range_scale) + self.incidence_range_bias_m * (1.0 - cos_incidence)

    def encoder_reading(self, head_angle_rad: np.ndarray) -> np.ndarray:
        """The encoder's reading [rad, clockwise, unwrapped] at the head's true angle."""
        amplitude = np.radians(self.eccentricity_deg)
        return head_angle_rad - amplitude * np.sin(head_angle_rad + np.radians(self.eccentricity_phase_deg))

    def stamp(self, firing_s: np.ndarray, revolution_start_s: np.ndarray) -> np.ndarray:
        """The time [s, INS clock] stamped on a return fired at firing_s in a revolution begun at
        revolution_start_s (both on the true clock)."""
        return (revolution_start_s if self.revolution_stamps else firing_s) + self.latency_s

    def ins_yaw_deg(self, time_s: np.ndarray, yaw_deg: np.ndarray) -> np.ndarray:
        """The INS's recorded yaw [deg] at its sample times, from the yaw it would record without drift."""
        return yaw_deg + self.heading_drift_deg_s * (time_s - time_s[0])

    def settings(self) -> dict:
        return {k: (bool(v) if isinstance(v, bool) else float(v)) for k, v in asdict(self).items()}

    def effects(self) -> dict:
        """truth/effects.yaml's entries of the departures switched on (RECORDING.md names and units)."""
        effects = {}
        if self.range_scale:
            effects["range_scale"] = {"scale": self.range_scale, "magnitude": self.range_scale, "unit": "1",
                                      "physics": "the time-of-flight clock runs fast: every distance the head "
                                                 "measures is the true one x (1 + scale)"}
        if self.incidence_range_bias_m:
            effects["incidence_range_bias"] = {
                "bias_m": self.incidence_range_bias_m, "magnitude": self.incidence_range_bias_m, "unit": "m",
                "physics": "the detector fires late on oblique footprints: the distance reads long by "
                           "bias (1 - cos incidence), bias at grazing"}
        if self.eccentricity_deg:
            effects["azimuth_eccentricity"] = {
                "amplitude_deg": self.eccentricity_deg, "phase_deg": self.eccentricity_phase_deg,
                "magnitude": self.eccentricity_deg, "unit": "deg",
                "physics": "the encoder disc is off the spin axis: the reading lags the head's angle psi by "
                           "amplitude sin(psi + phase)"}
        if self.latency_s:
            effects["time_offset"] = {"offset_s": self.latency_s, "magnitude": self.latency_s, "unit": "s",
                                      "physics": "every return is stamped this long after its laser fired "
                                                 "(INS clock)"}
        if self.heading_drift_deg_s:
            effects["heading_drift"] = {"rate_deg_s": self.heading_drift_deg_s,
                                        "magnitude": self.heading_drift_deg_s, "unit": "deg/s",
                                        "physics": "the INS yaw drifts from the truth at this rate from its "
                                                   "first pose"}
        return effects
