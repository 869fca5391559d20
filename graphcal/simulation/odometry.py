"""odometry.csv of a simulated drive: wheel angles (and a gyro yaw rate) from the true motion.

Eq. 1-2 of seed 002 inverted: the body origin (midpoint of the axle) travels s, the heading
turns by psi, so the wheels travel s -+ (track / 2) psi (left, right), and turn by that path
over the TRUE radius. Noise on each wheel's angle increment accumulates like wheel slip.
"""

from __future__ import annotations

import numpy as np

from graphcal.recording.odometry import Odometry
from graphcal.simulation.drive import Drive
from graphcal.simulation.ins import sample_times
from graphcal.simulation.scenario import OdometrySpec

_RATE_STEP_S = 1e-4  # central difference of the true heading for the yaw rate


def _heading_rad(drive: Drive, elapsed_s: np.ndarray, duration_s: float) -> np.ndarray:
    elapsed_s = np.clip(elapsed_s, 0.0, duration_s)
    return np.radians(drive.pose_at(elapsed_s)[1])


def simulate_odometry(drive: Drive, spec: OdometrySpec, start_time_s: float, duration_s: float,
                      rng: np.random.Generator) -> Odometry:
    """Wheel angles [rad] at spec.rate_hz over the drive (and its yaw rate [rad/s] if spec.gyro)."""
    elapsed = sample_times(0.0, duration_s, spec.rate_hz)
    distance = drive.distance(elapsed)
    heading = _heading_rad(drive, elapsed, duration_s)
    turned = heading - heading[0]
    true_radius = spec.wheel_radius_m * (1.0 + spec.wheel_radius_error)
    wheels = []
    for side in (-1.0, 1.0):  # left, right
        angle = (distance + side * 0.5 * spec.track_m * turned) / true_radius
        if spec.wheel_noise_rad > 0:
            slip = rng.normal(0.0, spec.wheel_noise_rad, len(angle) - 1)
            angle = angle + np.concatenate([[0.0], np.cumsum(slip)])
        wheels.append(angle)
    yaw_rate = None
    if spec.gyro:
        ahead = _heading_rad(drive, elapsed + _RATE_STEP_S, duration_s)
        behind = _heading_rad(drive, elapsed - _RATE_STEP_S, duration_s)
        span = np.clip(elapsed + _RATE_STEP_S, 0, duration_s) - np.clip(elapsed - _RATE_STEP_S, 0, duration_s)
        yaw_rate = (ahead - behind) / span
        if spec.gyro_noise_rad_s > 0:
            yaw_rate = yaw_rate + rng.normal(0.0, spec.gyro_noise_rad_s, len(yaw_rate))
    return Odometry(start_time_s + elapsed, wheels[0], wheels[1], spec.wheel_radius_m, spec.track_m, yaw_rate)
