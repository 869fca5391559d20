"""Block point-to-plane factor: one gtsam.CustomFactor for thousands of correspondences.

Residual of correspondence k between return p (fibre i) and return m (fibre j), eq. 4.4:

    r_k = sqrt(w_k) / sigma0 * n_k . (p_w - m_w)

with n_k the unit normal at p and w_k its planarity weight, both from the last association
refresh; n_k is held in p's lidar frame and turns with p's extrinsic and trajectory rotation
(world_normals), so that a rigid turn of the cloud leaves r unchanged: with world-fixed normals
it would not, and the pairs' along-surface offsets would pretend to observe a rotation the data
cannot see (the roll about the driving direction on a straight drive). sigma0 [m] is the nominal point noise (so r is whitened: the cost is
(W / sigma0^2) J with J the normalised energy of eq. 4.4/5.2 and W the weight sum). Both points
move: p and m are each placed at their own time between their own control times (eq. 5.4).

Keys of a block, by slot: intrinsic_p, intrinsic_m (Vector4; None for the reference fibre,
whose offsets stay zero), extrinsic (Pose3; None when held fixed), p_lo, p_hi, m_lo, m_hi
(Point3 or Pose3 trajectory corrections; None when the trajectory is not estimated).
Repeated keys (e.g. p and m in the same control interval) get their Jacobians summed.

A block may return its residual compressed: with A = QR the block's Jacobian, the factor
returns [Q^T r; ||r - Q Q^T r||] and Jacobian [R; 0]: the cost is exact and the linear system
small. Compression mixes rows, so robust losses use the stacked form with ReweightScheme.Scalar.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import partial

import gtsam
import numpy as np

from factors.world_point import Corrections, Returns, Turn, world_normals, world_points

SLOTS = ("intrinsic_p", "intrinsic_m", "extrinsic", "p_lo", "p_hi", "m_lo", "m_hi")


@dataclass(frozen=True)
class BlockKeys:
    """GTSAM keys of a block by slot; None = not estimated (the fixed value is used)."""

    intrinsic_p: int | None = None
    intrinsic_m: int | None = None
    extrinsic: int | None = None
    p_lo: int | None = None
    p_hi: int | None = None
    m_lo: int | None = None
    m_hi: int | None = None

    def first_slots(self) -> dict[int, str]:
        """Each distinct estimated key with the first slot holding it, in slot order."""
        out: dict[int, str] = {}
        for slot in SLOTS:
            key = getattr(self, slot)
            if key is not None and key not in out:
                out[key] = slot
        return out

    def unique(self) -> list[int]:
        """Distinct estimated keys, in slot order (the CustomFactor's key list)."""
        return list(self.first_slots())


@dataclass(frozen=True)
class FixedValues:
    """Values used for slots that are not estimated (current estimates held fixed); offsets (4,)
    for the block or (N,4) per correspondence."""

    offsets_p: np.ndarray = field(default_factory=lambda: np.zeros(4))
    offsets_m: np.ndarray = field(default_factory=lambda: np.zeros(4))
    extrinsic: gtsam.Pose3 = field(default_factory=gtsam.Pose3)


@dataclass(frozen=True)
class Block:
    """Correspondences of one block: returns p and m (N each), unit normal at p in p's lidar
    frame (N,3), weight (N,)."""

    p: Returns
    m: Returns
    normal: np.ndarray
    weight: np.ndarray
    keys: BlockKeys
    pose_corrections: bool = False
    fixed: FixedValues = field(default_factory=FixedValues)
    sigma0_m: float = 0.01

    def __len__(self) -> int:
        return len(self.weight)


def _control(values: gtsam.Values | None, key: int | None, n: int, pose: bool):
    """(translation (n,3), rotation (n,3,3) or None, rotation vector (n,3) or None) of one control slot."""
    if key is None:
        return (np.zeros((n, 3)), np.broadcast_to(np.eye(3), (n, 3, 3)) if pose else None,
                np.zeros((n, 3)) if pose else None)
    if pose:
        value = values.atPose3(key)
        return (np.broadcast_to(value.translation(), (n, 3)), np.broadcast_to(value.rotation().matrix(), (n, 3, 3)),
                np.broadcast_to(gtsam.Rot3.Logmap(value.rotation()), (n, 3)))
    return np.broadcast_to(values.atPoint3(key), (n, 3)), None, None


def residuals(block: Block, values: gtsam.Values, jacobians: bool = True):
    """Whitened residuals (N,) and, per distinct key, the Jacobian (N, dim) (dict key -> array)."""
    keys, n, pose = block.keys, len(block), block.pose_corrections
    offsets_p = values.atVector(keys.intrinsic_p) if keys.intrinsic_p is not None else block.fixed.offsets_p
    offsets_m = values.atVector(keys.intrinsic_m) if keys.intrinsic_m is not None else block.fixed.offsets_m
    E = values.atPose3(keys.extrinsic) if keys.extrinsic is not None else block.fixed.extrinsic
    R_E, t_E = E.rotation().matrix(), E.translation()

    def controls(lo, hi):
        (t_lo, r_lo, w_lo), (t_hi, r_hi, w_hi) = _control(values, lo, n, pose), _control(values, hi, n, pose)
        return Corrections(t_lo, t_hi, r_lo, r_hi, w_lo, w_hi)

    at_p, at_m = controls(keys.p_lo, keys.p_hi), controls(keys.m_lo, keys.m_hi)
    turn_p = Turn.of(at_p, block.p.alpha, jacobians)  # p's point and normal turn alike
    p_w, J_p = world_points(block.p, np.broadcast_to(offsets_p, (n, 4)), R_E, t_E, at_p, jacobians, turn_p)
    m_w, J_m = world_points(block.m, np.broadcast_to(offsets_m, (n, 4)), R_E, t_E, at_m, jacobians)
    n_w, J_n = world_normals(block.p, R_E, at_p, block.normal, jacobians, turn_p)
    scale = np.sqrt(block.weight) / block.sigma0_m
    r = scale * np.einsum("ni,ni->n", n_w, p_w - m_w)
    if not jacobians:
        return r, None
    sn, sd = scale[:, None] * n_w, scale[:, None] * (p_w - m_w)
    # d r = s n . (d p - d m) + s (p - m) . d n; the normal turns with p's extrinsic and controls
    terms = [(keys.intrinsic_p, sn, J_p.intrinsic, 1.0), (keys.intrinsic_m, sn, J_m.intrinsic, -1.0),
             (keys.extrinsic, sn, J_p.extrinsic, 1.0), (keys.extrinsic, sn, J_m.extrinsic, -1.0),
             (keys.extrinsic, sd, J_n.extrinsic, 1.0),
             (keys.p_lo, sn, J_p.control_lo, 1.0), (keys.p_hi, sn, J_p.control_hi, 1.0),
             (keys.p_lo, sd, J_n.control_lo, 1.0), (keys.p_hi, sd, J_n.control_hi, 1.0),
             (keys.m_lo, sn, J_m.control_lo, -1.0), (keys.m_hi, sn, J_m.control_hi, -1.0)]
    H: dict[int, np.ndarray] = {}
    for key, along, J, sign in terms:
        if key is not None:
            row = sign * np.einsum("ni,nij->nj", along, J)
            H[key] = H[key] + row if key in H else row
    return r, H


def compress(r: np.ndarray, A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """[Q^T r; ||r - Q Q^T r||] and [R; 0] from the reduced QR of A (N x K, N >= K)."""
    Q, R = np.linalg.qr(A, mode="reduced")
    z = Q.T @ r
    rest = np.sqrt(max(float(r @ r - z @ z), 0.0))
    return np.r_[z, rest], np.vstack([R, np.zeros((1, A.shape[1]))])


def key_widths(block: Block) -> dict[int, int]:
    """Tangent dimension of each distinct key: Vector4 intrinsics 4, Pose3 6, Point3 3."""
    return {key: 4 if slot.startswith("intrinsic") else 6 if (slot == "extrinsic" or block.pose_corrections) else 3
            for key, slot in block.keys.first_slots().items()}


def _error(block: Block, compressed: bool, this: gtsam.CustomFactor, values: gtsam.Values, H) -> np.ndarray:
    widths = key_widths(block)
    keys = list(widths)
    if compressed and H is None:  # cost only: any vector with the same norm will do
        r, _ = residuals(block, values, jacobians=False)
        out = np.zeros(sum(widths.values()) + 1)
        out[0] = np.linalg.norm(r)
        return out
    r, J = residuals(block, values, jacobians=H is not None)
    if compressed:
        r, R = compress(r, np.hstack([J[k] for k in keys]))
        J = dict(zip(keys, np.split(R, np.cumsum([widths[k] for k in keys])[:-1], axis=1)))
    if H is not None:
        for index, key in enumerate(keys):
            H[index] = np.asfortranarray(J[key])
    return r


def make_factor(block: Block, compressed: bool = True,
                robust: gtsam.noiseModel.mEstimator.Base | None = None) -> gtsam.CustomFactor:
    """The block as one CustomFactor. compressed: QR-compressed residual (needs N >= total key
    dimension and no robust loss). robust: an mEstimator created with ReweightScheme.Scalar,
    applied row by row to the stacked residual."""
    widths = key_widths(block)
    if compressed and robust is not None:
        raise ValueError("a robust loss needs the stacked residual (compressed=False)")
    if compressed and len(block) < sum(widths.values()):
        compressed = False  # too few rows to compress: stack them
    dim = sum(widths.values()) + 1 if compressed else len(block)
    noise = gtsam.noiseModel.Unit.Create(dim)
    if robust is not None:
        noise = gtsam.noiseModel.Robust.Create(robust, noise)
    return gtsam.CustomFactor(noise, list(widths), partial(_error, block, compressed))
