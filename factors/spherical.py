"""Spherical multi-beam lidar model, eq. 4.2 of seed 000, with analytic Jacobians.

Pure NumPy, no I/O. Sensor frame: x forward at azimuth 0, z up along the spin axis; the
azimuth theta turns clockwise seen from above (Velodyne convention), so y = -sin(theta).

The per-fibre *factory* terms of the HDL-64E model generalise eq. 4.2 without changing it
when they are zero:

    a = theta + d_theta + alpha_i            (alpha_i: factory azimuth offset, rad)
    e = phi_i + d_phi                        (phi_i: factory elevation, rad)
    r = rho + d_rho + r0_i                   (r0_i: factory range offset, m)
    h = r cos e - V_i sin e                  (V_i: vertical offset of the laser, m)
    x =  h cos a + H_i sin a                 (H_i: horizontal offset of the laser, m)
    y = -h sin a + H_i cos a
    z =  r sin e + V_i cos e + Hz

With alpha = r0 = V = H = 0 this is exactly eq. 4.2. The estimated offsets are the four of
eq. 4.2: (d_rho [m], d_theta [rad], d_phi [rad], Hz [m]), in that order everywhere.

Heads whose beams leave from a point on the spinning arm (Ouster: lidar_origin_to_beam_origin_mm)
add a beam-origin term B_i [m]: the beam starts B_i from the spin axis along the *encoder*
direction theta (not along a), and the measured range counts from the spin axis, so B_i comes
off the range (Ouster sensor docs, "Lidar Range to XYZ"):

    r = rho + d_rho + r0_i - B_i
    p = (eq. above with this r) + B_i (cos theta, -sin theta, 0)

The added vector does not depend on the offsets, so the Jacobian keeps its form with this r.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

OFFSET_NAMES = ("d_range_m", "d_azimuth_rad", "d_elevation_rad", "h_z_m")


@dataclass(frozen=True)
class FactoryTerms:
    """Per-return factory model terms (arrays broadcastable to the returns).

    elevation_rad: phi_i; azimuth_offset_rad: alpha_i; range_offset_m: r0_i;
    vertical_offset_m: V_i; horizontal_offset_m: H_i; height_offset_m: Z_i;
    beam_origin_m: B_i, the beam origin's distance from the spin axis along the encoder direction.
    """

    elevation_rad: np.ndarray
    azimuth_offset_rad: np.ndarray | float = 0.0
    range_offset_m: np.ndarray | float = 0.0
    vertical_offset_m: np.ndarray | float = 0.0
    horizontal_offset_m: np.ndarray | float = 0.0
    height_offset_m: np.ndarray | float = 0.0
    beam_origin_m: np.ndarray | float = 0.0


def _angles(range_m, azimuth_rad, factory: FactoryTerms, offsets):
    d_rho, d_theta, d_phi, _ = (offsets[..., k] for k in range(4))
    a = azimuth_rad + d_theta + factory.azimuth_offset_rad
    e = factory.elevation_rad + d_phi
    r = range_m + d_rho + factory.range_offset_m - factory.beam_origin_m
    return a, e, r


def _beam_origin(azimuth_rad, factory: FactoryTerms) -> np.ndarray:
    """B_i (cos theta, -sin theta, 0): where the beam leaves the spinning arm, (..., 3) [m]."""
    B = factory.beam_origin_m
    return np.stack(np.broadcast_arrays(B * np.cos(azimuth_rad), -B * np.sin(azimuth_rad), 0.0 * azimuth_rad),
                    axis=-1)


def to_xyz(range_m, azimuth_rad, factory: FactoryTerms, offsets) -> np.ndarray:
    """Raw (range [m], encoder azimuth [rad]) -> sensor-frame xyz [m], eq. 4.2.

    offsets: (..., 4) per-return (d_rho m, d_theta rad, d_phi rad, Hz m).
    Returns (..., 3).
    """
    xyz, _ = to_xyz_with_jacobian(range_m, azimuth_rad, factory, offsets, jacobian=False)
    return xyz


def to_xyz_with_jacobian(range_m, azimuth_rad, factory: FactoryTerms, offsets, jacobian=True,
                         elevation_trig: tuple[np.ndarray, np.ndarray] | None = None):
    """Eq. 4.2 and its Jacobian d xyz / d offsets, shape (..., 3, 4) (eq. 4.3 terms p'_2..p'_5).

    elevation_trig: (cos e, sin e) per return when the caller has them (e = phi_i + d_phi is one
    angle per fibre: a caller that knows the fibres takes its cosine once per fibre)."""
    offsets = np.asarray(offsets, dtype=np.float64)
    a, e, r = _angles(range_m, azimuth_rad, factory, offsets)
    V, H = factory.vertical_offset_m, factory.horizontal_offset_m
    ca, sa = np.cos(a), np.sin(a)
    ce, se = elevation_trig if elevation_trig is not None else (np.cos(e), np.sin(e))
    vertical, horizontal = np.any(V), np.any(H)  # the terms of a zero factory offset are skipped, not added
    h = r * ce - V * se if vertical else r * ce
    xyz = np.empty(np.broadcast_shapes(np.shape(h), np.shape(ca), np.shape(offsets)[:-1]) + (3,))
    np.multiply(h, ca, out=xyz[..., 0])
    np.multiply(-h, sa, out=xyz[..., 1])
    np.multiply(r, se, out=xyz[..., 2])
    if horizontal:
        xyz[..., 0] += H * sa
        xyz[..., 1] += H * ca
    if vertical:
        xyz[..., 2] += V * ce
    xyz[..., 2] += offsets[..., 3]
    if np.any(factory.height_offset_m):
        xyz[..., 2] += factory.height_offset_m
    if np.any(factory.beam_origin_m):
        xyz = xyz + _beam_origin(azimuth_rad, factory)
    if not jacobian:
        return xyz, None
    J = np.zeros(xyz.shape + (4,))
    # d/d rho (eq. 4.3, p'_2)
    J[..., 0, 0], J[..., 1, 0], J[..., 2, 0] = ce * ca, -ce * sa, se
    # d/d theta (eq. 4.3, p'_3)
    J[..., 0, 1], J[..., 1, 1] = -h * sa + H * ca, -h * ca - H * sa
    # d/d phi (eq. 4.3, p'_4)
    dh = -r * se - V * ce
    J[..., 0, 2], J[..., 1, 2], J[..., 2, 2] = dh * ca, -dh * sa, r * ce - V * se
    # d/d Hz (eq. 4.3, p'_5)
    J[..., 2, 3] = 1.0
    return xyz, J


def beam_rays(azimuth_rad, factory: FactoryTerms, offsets) -> tuple[np.ndarray, np.ndarray]:
    """Origin and unit direction of each beam in the sensor frame: xyz = origin + r * direction.

    r is the corrected range rho + d_rho + r0. Used by the simulator to cast rays.
    """
    azimuth_rad = np.asarray(azimuth_rad, dtype=np.float64)
    offsets = np.broadcast_to(np.asarray(offsets, dtype=np.float64), azimuth_rad.shape + (4,))
    range_at_origin = factory.beam_origin_m - (offsets[..., 0] + factory.range_offset_m)  # raw range giving r = 0
    return to_xyz(range_at_origin, azimuth_rad, factory, offsets), beam_directions(azimuth_rad, factory, offsets)


def beam_directions(azimuth_rad, factory: FactoryTerms, offsets,
                    elevation_trig: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Unit direction (..., 3) of each beam in the sensor frame, d xyz / d r of eq. 4.2 (eq. 4.3, p'_2): the same at
    every range, so no point is placed for it. elevation_trig: as to_xyz_with_jacobian's."""
    a, e, _ = _angles(0.0, np.asarray(azimuth_rad, dtype=np.float64), factory, np.asarray(offsets, dtype=np.float64))
    ce, se = elevation_trig if elevation_trig is not None else (np.cos(e), np.sin(e))
    return np.stack(np.broadcast_arrays(ce * np.cos(a), -ce * np.sin(a), se), axis=-1)


def from_xyz(xyz, factory: FactoryTerms, offsets) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Inverse of eq. 4.2: sensor-frame xyz of fibre returns -> (range m, encoder azimuth rad).

    Also returns the off-cone distance [m]: how far the point lies from the fibre's cone
    (0 for a point the model can produce). Azimuth is wrapped to [0, 2 pi).
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    offsets = np.asarray(offsets, dtype=np.float64)
    x, y, z = xyz[..., 0], xyz[..., 1], xyz[..., 2] - offsets[..., 3] - factory.height_offset_m
    V, B = factory.vertical_offset_m, factory.beam_origin_m
    e = factory.elevation_rad + offsets[..., 2]
    # the beam origin B (cos theta, -sin theta) with theta = a - delta is B cos(delta) along the beam's
    # horizontal direction plus B sin(delta) along the horizontal offset's: fold it into h and H
    delta = offsets[..., 1] + factory.azimuth_offset_rad
    along, H = B * np.cos(delta), factory.horizontal_offset_m + B * np.sin(delta)
    # x - i y = (h - i H) exp(-i a)... written with psi = atan2(-y, x): a = psi + atan2(H, h)
    h = np.sqrt(np.maximum(x * x + y * y - np.square(H), 0.0))
    a = np.arctan2(-y, x) + np.arctan2(H, h)
    h = h - along
    r = h * np.cos(e) + z * np.sin(e)
    off_cone = z * np.cos(e) - h * np.sin(e) - V
    range_m = r - offsets[..., 0] - factory.range_offset_m + B
    azimuth = np.mod(a - offsets[..., 1] - factory.azimuth_offset_rad, 2 * np.pi)
    return range_m, azimuth, off_cone
