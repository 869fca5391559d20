"""The spinning head: a Velodyne HDL-32E as its manual describes it, implemented here from the
recording contract (RECORDING.md), not from graphcal.

- 32 lasers fired in blocks: one block every 46.08 us, the lasers of a block 1.152 us apart in
  firing order (fibre id = position in the block).
- The head turns clockwise seen from above at about 600 rpm; the rate wanders slowly (default
  599.5-600.5 rpm). The block rate is the firing clock and does not follow the spin.
- A laser fired at t leaves along the head angle psi(t) plus its own azimuth offset; the recorded
  azimuth is the encoder angle interpolated at that firing time, psi(t), plus an optional
  per-revolution encoder error (jitter, a departure from the contract's model).
- Beam of fibre k in the lidar frame: origin (0, 0, Hz_k), direction
  (cos(a) cos(e), -sin(a) cos(e), sin(e)) with a = psi + d_theta_k, e = phi_k + d_phi_k.
  A hit at distance d along it is reported as range d - d_rho_k (+ noise).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MODEL = "HDL-32E"
ROTATION_HZ = 10.0
REFERENCE_FIBRE = 15
# HDL-32E nominal elevations [deg] in firing order (user manual: -30.67 .. +10.67 in 4/3 deg
# steps, interleaved low/high; laser 15 at 0 deg).
ELEVATION_DEG = np.array([-30.67, -9.33, -29.33, -8.00, -28.00, -6.67, -26.67, -5.33, -25.33, -4.00,
                          -24.00, -2.67, -22.67, -1.33, -21.33, 0.00, -20.00, 1.33, -18.67, 2.67,
                          -17.33, 4.00, -16.00, 5.33, -14.67, 6.67, -13.33, 8.00, -12.00, 9.33,
                          -10.67, 10.67])
N_FIBRES = len(ELEVATION_DEG)
BLOCK_PERIOD_S = 46.08e-6
LASER_SPACING_S = 1.152e-6
MIN_RANGE_M = 1.0
MAX_RANGE_M = 100.0


def draw_intrinsics(rng, bounds) -> np.ndarray:
    """(32, 4) true offsets (d_rho m, d_theta rad, d_phi rad, Hz m), uniform within
    bounds = (m, deg, deg, m); the reference fibre is exactly zero."""
    b = np.asarray(bounds, dtype=np.float64)
    offsets = rng.uniform(-1.0, 1.0, (N_FIBRES, 4)) * b
    offsets[:, 1:3] = np.radians(offsets[:, 1:3])
    offsets[REFERENCE_FIBRE] = 0.0
    return offsets


@dataclass(frozen=True)
class HeadSpin:
    """Head angle psi(t) [rad, clockwise, unwrapped] with a wandering spin rate.

    rpm(t) = 600 + wander_rpm * sum_i w_i sin(2 pi f_i tau + p_i), sum w_i = 1, tau = t - t0;
    psi is its exact integral."""

    t0: float
    psi0: float
    wander_rpm: float
    freqs_hz: np.ndarray
    phases: np.ndarray
    weights: np.ndarray
    nominal_rpm: float = 60.0 * ROTATION_HZ

    @classmethod
    def draw(cls, t0: float, rng, wander_rpm: float) -> HeadSpin:
        k = 3
        weights = rng.uniform(0.2, 1.0, k)
        return cls(t0=t0, psi0=float(rng.uniform(0.0, 2 * np.pi)), wander_rpm=wander_rpm,
                   freqs_hz=1.0 / rng.uniform(1.5, 12.0, k), phases=rng.uniform(0, 2 * np.pi, k),
                   weights=weights / weights.sum())

    def rpm(self, t) -> np.ndarray:
        tau = np.asarray(t, dtype=np.float64)[..., None] - self.t0
        return self.nominal_rpm + self.wander_rpm * np.sum(
            self.weights * np.sin(2 * np.pi * self.freqs_hz * tau + self.phases), axis=-1)

    def angle(self, t) -> np.ndarray:
        tau = np.asarray(t, dtype=np.float64) - self.t0
        w = 2 * np.pi * self.freqs_hz
        wander = np.sum(self.weights / w * (np.cos(self.phases) - np.cos(w * tau[..., None] + self.phases)), axis=-1)
        return self.psi0 + 2 * np.pi / 60.0 * (self.nominal_rpm * tau + self.wander_rpm * wander)

    def time_at(self, angle_rad) -> np.ndarray:
        """The time [s] at which the head reaches an (unwrapped) angle: psi's inverse, by Newton's method
        from the nominal rate (the wander moves the rate by under 0.1 %; five steps reach 1e-12 s)."""
        target = np.asarray(angle_rad, dtype=np.float64)
        t = self.t0 + (target - self.psi0) / (2 * np.pi * self.nominal_rpm / 60.0)
        for _ in range(5):
            t = t - (self.angle(t) - target) / (2 * np.pi * self.rpm(t) / 60.0)
        return t


def beam_directions(head_angle: np.ndarray, fibre: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """(N, 3) unit beam directions in the lidar frame."""
    a = head_angle + offsets[fibre, 1]
    e = np.radians(ELEVATION_DEG)[fibre] + offsets[fibre, 2]
    ce = np.cos(e)
    return np.column_stack([np.cos(a) * ce, -np.sin(a) * ce, np.sin(e)])


def detection_strength(reflectivity, cos_incidence, distance, material_retro) -> np.ndarray:
    """Received signal (relative) of a diffuse (or retro-reflective) surface at a distance."""
    lambert = np.where(material_retro, np.power(np.clip(cos_incidence, 1e-3, 1.0), 0.2), cos_incidence)
    return reflectivity * lambert / (1.0 + (distance / 40.0) ** 2)
