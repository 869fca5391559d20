"""Planar dead reckoning from wheel odometry, eq. 1-3 of seed 002 (Merriaux et al. 2016).

Wheel angles [rad] -> linear and angular increments (eq. 1, 2), or the angular increment from
a gyro yaw rate when odometry.csv has one (the seed's vehicle took it from the ESP gyro), then
midpoint Runge-Kutta integration (eq. 3) into poses (x, y, theta) of the body in an odometry
frame whose origin is the first sample. Wheel odometry is 2D: z, roll and pitch stay 0, so a
slope or a body roll during the sweep is not compensated.
"""

from __future__ import annotations

import numpy as np

from graphcal.recording.odometry import Odometry
from graphcal.recording.poses import PoseTrack


def increments(odometry: Odometry, use_gyro: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """(dx [m], dtheta [rad]) between successive samples, shape (M-1,) each.

    use_gyro: take dtheta from the yaw rate (trapezoidal rule) when odometry.csv has one.
    """
    d_left = np.diff(odometry.wheel_left_rad)
    d_right = np.diff(odometry.wheel_right_rad)
    r, track = odometry.wheel_radius_m, odometry.track_m
    dx = r * (d_right + d_left) / 2.0  # eq. 1
    if use_gyro and odometry.yaw_rate_rad_s is not None:
        rate = odometry.yaw_rate_rad_s
        dtheta = 0.5 * (rate[1:] + rate[:-1]) * np.diff(odometry.time)
    else:
        dtheta = r * (d_right - d_left) / track  # eq. 2
    return dx, dtheta


def integrate(dx: np.ndarray, dtheta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eq. 3 (midpoint Runge-Kutta): increments (M-1,) -> x, y [m], theta [rad], each (M,),
    starting at (0, 0, 0). Exact in heading and direction for constant-curvature steps."""
    theta = np.concatenate([[0.0], np.cumsum(dtheta)])
    heading = theta[:-1] + 0.5 * dtheta
    x = np.concatenate([[0.0], np.cumsum(dx * np.cos(heading))])
    y = np.concatenate([[0.0], np.cumsum(dx * np.sin(heading))])
    return x, y, theta


def odometry_track(odometry: Odometry, use_gyro: bool = True) -> PoseTrack:
    """T_odom_body(t): the body's planar poses integrated from the wheels (and gyro)."""
    x, y, theta = integrate(*increments(odometry, use_gyro))
    rpy_deg = np.column_stack([np.zeros_like(theta), np.zeros_like(theta), np.degrees(theta)])
    return PoseTrack.from_rpy(odometry.time, np.column_stack([x, y, np.zeros_like(x)]), rpy_deg)
