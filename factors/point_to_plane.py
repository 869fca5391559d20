"""Block point-to-plane factor: one gtsam.CustomFactor for thousands of correspondences.

Residual of correspondence k between return p (fibre i) and return m (fibre j), eq. 4.4:

    r_k = sqrt(w_k) / sigma0 * n_k . (p_w - m_w)

with n_k the unit normal at p and w_k its planarity weight, both from the last association
refresh; n_k is held in p's lidar frame and turns with p's extrinsic and trajectory rotation
(world_normals), so that a rigid turn of the cloud leaves r unchanged: with world-fixed normals
it would not, and the pairs' along-surface offsets would pretend to observe a rotation the data
cannot see (the roll about the driving direction on a straight drive). sigma0 [m] is the nominal
point noise (so r is whitened: the cost is (W / sigma0^2) J with J the normalised energy of eq.
4.4/5.2 and W the weight sum), or one sigma per pair (along its lines of sight, incidence_sigma_m).
Both points move: p and m are each placed at their own time between their own control times
(eq. 5.4); each may be placed at its range's stand-in plus an offset held in its sensor frame
(Block.p_held_l), so that its own range noise stays out of the Jacobians (docs/reference/math.md).

Keys of a row, by slot: intrinsic_p, intrinsic_m (Vector4; none for the reference fibre, whose
offsets stay zero), extrinsic (Pose3, one for the whole block; none when held fixed), p_lo, p_hi,
m_lo, m_hi (Point3 or Pose3 trajectory corrections; none when the trajectory is not estimated).
The keys of the row slots vary from row to row, so that one block holds many fibre pairs and
control intervals (few, large blocks: each Python callback costs ~23 us, each NumPy call a few);
the factor's keys are the distinct keys of its rows, and a key held by several slots of a row
(p and m in the same control interval) gets the slots' Jacobians summed.

A block may also estimate candidate left-out effects (factors/effects.py): one Vector key per
candidate, shared by every row, perturbing p's and m's raw values and poses (m's only when m is a
return of the same recording, not a fixed map point).

A block may return its residual compressed: with R^T R = A^T A (A the block's Jacobian) and
R^T z = A^T r, the factor returns [z; (||r||^2 - ||z||^2)^1/2] and Jacobian [R; 0] (as Q^T r
and R of a QR of A would be): the cost is exact and the linear system small. Compression mixes rows, so robust losses use the stacked form with ReweightScheme.Scalar.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property, partial

import gtsam
import numpy as np
import scipy.linalg

from factors.channels import Basis, Channels, Motion, channel_jacobians, perturbed
from factors.world_point import Corrections, Placed, Returns, Turn, world_normals, world_points

ROW_SLOTS = ("intrinsic_p", "intrinsic_m", "p_lo", "p_hi", "m_lo", "m_hi")
NO_KEY = -1


@dataclass(frozen=True)
class BlockKeys:
    """GTSAM keys of a block: per row slot an (N,) int64 array of keys (NO_KEY: not estimated,
    the fixed value is used); the extrinsic key or None."""

    intrinsic_p: np.ndarray
    intrinsic_m: np.ndarray
    p_lo: np.ndarray
    p_hi: np.ndarray
    m_lo: np.ndarray
    m_hi: np.ndarray
    extrinsic: int | None = None

    @classmethod
    def of(cls, n: int, extrinsic: int | None = None, **slots) -> BlockKeys:
        """Keys of n rows; each row slot given as None (no key), one key for every row, or (n,) keys."""
        unknown = set(slots) - set(ROW_SLOTS)
        if unknown:
            raise TypeError(f"unknown slots {sorted(unknown)}")
        arrays = {slot: np.broadcast_to(np.asarray(NO_KEY if slots.get(slot) is None else slots[slot], np.int64), (n,))
                  for slot in ROW_SLOTS}
        return cls(extrinsic=extrinsic, **arrays)

    def __len__(self) -> int:
        return len(self.intrinsic_p)

    @cached_property
    def unique(self) -> tuple[int, ...]:
        """Distinct estimated keys (the CustomFactor's key list): intrinsics, extrinsic, controls."""
        intrinsics = np.unique(np.r_[self.intrinsic_p, self.intrinsic_m])
        controls = np.unique(np.r_[self.p_lo, self.p_hi, self.m_lo, self.m_hi])
        extrinsic = [] if self.extrinsic is None else [self.extrinsic]
        return tuple(int(k) for k in intrinsics if k != NO_KEY) + tuple(extrinsic) + \
            tuple(int(k) for k in controls if k != NO_KEY)

    def distinct(self, *slots: str) -> tuple[np.ndarray, np.ndarray]:
        """Distinct keys of the slots' rows (NO_KEY included) and each row's index into them,
        (N * len(slots),), slot after slot."""
        if slots not in self._distinct:
            distinct, inverse = np.unique(np.concatenate([getattr(self, slot) for slot in slots]), return_inverse=True)
            self._distinct[slots] = (distinct, inverse.ravel())
        return self._distinct[slots]

    @cached_property
    def _distinct(self) -> dict:
        return {}

    def column(self, slot: str, offsets: dict[int, int]) -> np.ndarray:
        """(N,) first Jacobian column of each row's key in a slot (NO_KEY where none)."""
        distinct, inverse = self.distinct(slot)
        return np.array([offsets.get(int(k), NO_KEY) for k in distinct], np.int64)[inverse]


@dataclass(frozen=True)
class FixedValues:
    """Values used for slots that are not estimated (current estimates held fixed); offsets (4,)
    for the block or (N,4) per correspondence. Controls without a key are zero corrections."""

    offsets_p: np.ndarray = field(default_factory=lambda: np.zeros(4))
    offsets_m: np.ndarray = field(default_factory=lambda: np.zeros(4))
    extrinsic: gtsam.Pose3 = field(default_factory=gtsam.Pose3)


@dataclass(frozen=True)
class EffectTerms:
    """Candidate effects a block estimates: one Vector key per candidate (shared by all rows), the
    candidates' bases over p's and m's returns (m_bases None: m is a fixed map point the effects do
    not move) and the INS motion at p's and m's times."""

    keys: tuple[int, ...]
    p_bases: tuple[Basis, ...]
    p_motion: Motion
    m_bases: tuple[Basis, ...] | None = None
    m_motion: Motion | None = None


@dataclass(frozen=True)
class Block:
    """Correspondences of one block: returns p and m (N each), unit normal at p in p's lidar
    frame (N,3), weight (N,), noise sigma0_m [m] of every residual n.(p - m) (one, or (N,)); p_held_l,
    m_held_l (N,3) [m]: offsets in each return's sensor frame added to p and m and held fixed (None:
    none), so that the intrinsic offsets move p and m as their ranges' stand-ins while p and m are the
    measured points where the block was made (factors.world_point.on_stand_ins); the offsets
    turn with the sensor, so a rigid turn of the whole cloud leaves every residual as it was."""

    p: Returns
    m: Returns
    normal: np.ndarray
    weight: np.ndarray
    keys: BlockKeys
    pose_corrections: bool = False
    fixed: FixedValues = field(default_factory=FixedValues)
    sigma0_m: float | np.ndarray = 0.01
    effects: EffectTerms | None = None
    p_held_l: np.ndarray | None = None
    m_held_l: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.weight)

    @cached_property
    def widths(self) -> dict[int, int]:
        """Tangent dimension of each distinct key: Vector4 intrinsics 4, Pose3 6, Point3 3."""
        intrinsics = set(np.r_[self.keys.intrinsic_p, self.keys.intrinsic_m].tolist())
        control = 6 if self.pose_corrections else 3
        widths = {key: 4 if key in intrinsics else 6 if key == self.keys.extrinsic else control
                  for key in self.keys.unique}
        if self.effects is not None:
            widths.update({key: basis.dim for key, basis in zip(self.effects.keys, self.effects.p_bases)})
        return widths

    @cached_property
    def offsets(self) -> dict[int, int]:
        """First column of each key in the block's Jacobian."""
        starts = np.cumsum([0] + list(self.widths.values()))
        return dict(zip(self.widths, starts[:-1].tolist()))

    def entries(self, slot: str, width: int) -> tuple[np.ndarray | slice, np.ndarray]:
        """The rows that have a key in a row slot (a slice when all do) and, for each, the flat indices (rows x
        width) of its key's columns in the block's Jacobian (N x sum of widths, C order), computed once."""
        if (slot, width) not in self._entries:
            start = self.keys.column(slot, self.offsets)
            has = np.flatnonzero(start != NO_KEY)
            flat = (has * sum(self.widths.values()) + start[has])[:, None] + np.arange(width)
            self._entries[slot, width] = (slice(None) if len(has) == len(start) else has, flat)
        return self._entries[slot, width]

    @cached_property
    def _entries(self) -> dict:
        return {}


INCIDENCE_FLOOR = 0.1  # of the range noise: a pair's sigma for normal errors


def incidence_sigma_m(normal: np.ndarray, ray_p: np.ndarray, ray_m: np.ndarray, range_sigma_m: float,
                      out_of_plane_m: np.ndarray | float = 0.0) -> np.ndarray:
    """(N,) sigma [m] of n.(p - m) when the range noise (range_sigma_m) moves p and m along their unit
    lines of sight ray_p, ray_m (N,3) and the surface departs from the plane at p by out_of_plane_m
    [m] ((N,) or a scalar; the plane model's error, and any other independent error of the pair, e.g.
    pose_noise_sigma_m in quadrature):
    (range_sigma^2 ((n.u_p)^2 + (n.u_m)^2 + INCIDENCE_FLOOR^2) + out_of_plane^2)^1/2."""
    along_p = np.einsum("ni,ni->n", normal, ray_p)
    along_m = np.einsum("ni,ni->n", normal, ray_m)
    return range_sigma_m * np.sqrt(along_p ** 2 + along_m ** 2 + INCIDENCE_FLOOR ** 2
                                   + np.square(np.asarray(out_of_plane_m) / range_sigma_m))


def pose_noise_sigma_m(normal: np.ndarray, lever_p_m: np.ndarray, lever_m_m: np.ndarray, dt_s: np.ndarray,
                       interval_s: float, position_sigma_m: float, attitude_sigma_rad: float) -> np.ndarray:
    """(N,) sigma [m] that white noise on the recorded poses adds to n.(p - m): position noise
    position_sigma_m per axis and attitude noise attitude_sigma_rad per axis on each pose sample,
    interval_s apart, each return's pose interpolated linearly between two samples (variance factor
    (1-a)^2 + a^2, 2/3 on average). lever_p_m, lever_m_m (N,3): p and m minus the body position at their
    times [m, world axes]; dt_s (N,): their time apart. Returns fired within one pose interval share its
    noise, which then moves both alike: the shared part's weight falls linearly with dt_s / interval_s.
    Position: 2 (2/3) s^2 f; attitude: (2/3) sa^2 (f (|l_p x n|^2 + |l_m x n|^2) + (1 - f) |(l_p - l_m) x n|^2),
    f = min(|dt_s| / interval_s, 1)."""
    if interval_s <= 0 or (position_sigma_m == 0 and attitude_sigma_rad == 0):
        return np.zeros(len(normal))
    apart = np.minimum(np.abs(dt_s) / interval_s, 1.0)
    arm_p, arm_m = np.cross(lever_p_m, normal), np.cross(lever_m_m, normal)
    arm_pm = arm_p - arm_m
    attitude = (apart * (np.einsum("ni,ni->n", arm_p, arm_p) + np.einsum("ni,ni->n", arm_m, arm_m))
                + (1.0 - apart) * np.einsum("ni,ni->n", arm_pm, arm_pm))
    return np.sqrt(2.0 / 3.0 * (2.0 * apart * position_sigma_m ** 2 + attitude_sigma_rad ** 2 * attitude))


def _intrinsics(values: gtsam.Values, keys: BlockKeys, slot: str, fixed: np.ndarray) -> np.ndarray:
    """(N,4) offsets of each row: its key's value in a slot, or the fixed value where it has none."""
    distinct, inverse = keys.distinct(slot)
    table = np.array([values.atVector(int(k)) if k != NO_KEY else np.zeros(4) for k in distinct])
    none = (getattr(keys, slot) == NO_KEY)[:, None]
    if not none.any():
        return table[inverse]
    return np.where(none, np.broadcast_to(fixed, (len(keys), 4)), table[inverse])


def _corrections(values: gtsam.Values, keys: BlockKeys, lo: str, hi: str, pose: bool) -> Corrections:
    """Per-row corrections at each row's lo and hi control (zero where a slot has no key)."""
    distinct, inverse = keys.distinct(lo, hi)
    n = len(keys)
    if pose:
        poses = [values.atPose3(int(k)) if k != NO_KEY else gtsam.Pose3() for k in distinct]
        t = np.array([p.translation() for p in poses])[inverse]
        R = np.array([p.rotation().matrix() for p in poses])[inverse]
        w = np.array([gtsam.Rot3.Logmap(p.rotation()) for p in poses])[inverse]
        return Corrections(t[:n], t[n:], R[:n], R[n:], w[:n], w[n:])
    t = np.array([values.atPoint3(int(k)) if k != NO_KEY else np.zeros(3) for k in distinct])[inverse]
    return Corrections(t[:n], t[n:])


def residuals(block: Block, values: gtsam.Values, jacobians: bool = True):
    """Whitened residuals (N,) and, if asked, the block's Jacobian (N, sum of key widths), its
    columns in the order of block.widths."""
    keys, n, pose = block.keys, len(block), block.pose_corrections
    offsets_p = _intrinsics(values, keys, "intrinsic_p", block.fixed.offsets_p)
    offsets_m = _intrinsics(values, keys, "intrinsic_m", block.fixed.offsets_m)
    E = values.atPose3(keys.extrinsic) if keys.extrinsic is not None else block.fixed.extrinsic
    R_E, t_E = E.rotation().matrix(), E.translation()
    at_p = _corrections(values, keys, "p_lo", "p_hi", pose)
    at_m = _corrections(values, keys, "m_lo", "m_hi", pose)
    effects = _Effects.of(block, values)
    p, m = effects.returns(block.p, "p"), effects.returns(block.m, "m")
    turn_p = Turn.of(at_p, p.alpha, jacobians)  # p's point and normal turn alike
    turn_m = Turn.of(at_m, m.alpha, jacobians)
    p_w, J_p = world_points(p, offsets_p, R_E, t_E + effects.body("p"), at_p, jacobians, turn_p, block.p_held_l)
    m_w, J_m = world_points(m, offsets_m, R_E, t_E + effects.body("m"), at_m, jacobians, turn_m, block.m_held_l)
    placed_p = Placed(p, offsets_p, R_E, at_p, turn_p, p_w, J_p)
    placed_m = Placed(m, offsets_m, R_E, at_m, turn_m, m_w, J_m)
    n_w, J_n = world_normals(p, R_E, at_p, block.normal, jacobians, turn_p)
    scale = np.sqrt(block.weight) / block.sigma0_m
    r = scale * np.einsum("ni,ni->n", n_w, p_w - m_w)
    if not jacobians:
        return r, None
    sn, sd = scale[:, None] * n_w, scale[:, None] * (p_w - m_w)
    # d r = s n . (d p - d m) + s (p - m) . d n; the normal turns with p's extrinsic and controls
    extrinsic = (np.einsum("ni,nij->nj", sn, J_p.extrinsic - J_m.extrinsic)
                 + np.einsum("ni,nij->nj", sd, J_n.extrinsic))
    terms = [("intrinsic_p", np.einsum("ni,nij->nj", sn, J_p.intrinsic)),
             ("intrinsic_m", -np.einsum("ni,nij->nj", sn, J_m.intrinsic)),
             ("p_lo", np.einsum("ni,nij->nj", sn, J_p.control_lo) + np.einsum("ni,nij->nj", sd, J_n.control_lo)),
             ("p_hi", np.einsum("ni,nij->nj", sn, J_p.control_hi) + np.einsum("ni,nij->nj", sd, J_n.control_hi)),
             ("m_lo", -np.einsum("ni,nij->nj", sn, J_m.control_lo)),
             ("m_hi", -np.einsum("ni,nij->nj", sn, J_m.control_hi))]
    A = np.zeros((n, sum(block.widths.values())))
    if keys.extrinsic is not None:
        A[:, block.offsets[keys.extrinsic]:block.offsets[keys.extrinsic] + 6] = extrinsic
    for key, J in effects.jacobians(placed_p, placed_m, n_w, sn, sd):
        A[:, block.offsets[key]:block.offsets[key] + J.shape[1]] = J
    flat = A.reshape(-1)  # a view
    for slot, J in terms:
        has, entries = block.entries(slot, J.shape[1])
        if len(entries):  # one key per row and slot: no (row, column) repeats within one assignment
            flat[entries] += J[has]
    return r, A


@dataclass(frozen=True)
class _Effects:
    """A block's candidate effects at given values: channel values of p and m (None: not moved)."""

    terms: EffectTerms | None
    channels: dict

    @classmethod
    def of(cls, block: Block, values: gtsam.Values) -> _Effects:
        terms = block.effects
        if terms is None:
            return cls(None, {})
        thetas = [values.atVector(int(key)) for key in terms.keys]
        channels = {"p": Channels.of(terms.p_bases, thetas, len(block))}
        if terms.m_bases is not None:
            channels["m"] = Channels.of(terms.m_bases, thetas, len(block))
        return cls(terms, channels)

    def _motion(self, side: str) -> Motion:
        return self.terms.p_motion if side == "p" else self.terms.m_motion

    def returns(self, returns: Returns, side: str) -> Returns:
        return returns if side not in self.channels else perturbed(returns, self._motion(side), self.channels[side])

    def body(self, side: str):
        return self.channels[side].body if side in self.channels else 0.0

    def jacobians(self, p: Placed, m: Placed, n_w: np.ndarray, sn: np.ndarray, sd: np.ndarray):
        """(key, d r / d theta (N, dim)) of each candidate: s n . (dp - dm) + s (p - m) . dn, with p's and m's
        returns placed in the world, the normal n_w at p, sn = s n and sd = s (p - m)."""
        if self.terms is None:
            return []
        at = {"p": channel_jacobians(p, self._motion("p"), self.channels["p"], n_w)}
        if "m" in self.channels:
            at["m"] = channel_jacobians(m, self._motion("m"), self.channels["m"])
        out = []
        for index, key in enumerate(self.terms.keys):
            basis_p = self.terms.p_bases[index]
            J = np.einsum("ni,nij->nj", sn, at["p"].of_candidate(basis_p))
            turned = at["p"].normal_of_candidate(basis_p)
            if turned is not None:
                J = J + np.einsum("ni,nij->nj", sd, turned)
            if "m" in at:
                J = J - np.einsum("ni,nij->nj", sn, at["m"].of_candidate(self.terms.m_bases[index]))
            out.append((key, J))
        return out


def jacobian_by_key(block: Block, A: np.ndarray) -> dict[int, np.ndarray]:
    """The columns of a block Jacobian (or of its compressed R) of each key."""
    return {key: A[:, start:start + block.widths[key]] for key, start in block.offsets.items()}


def compress(r: np.ndarray, A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(z, R) with R^T R = A^T A, R^T z = A^T r and ||z||^2 = ||r||^2 (the last entry of z holds
    the norm of the rest of r), R with one row per column of A plus a zero row.

    From the column-scaled Gram matrix B^T B = D^-1 A^T A D^-1 (B = A D^-1, D the column norms, read off A^T A's
    diagonal): one N x K matrix product (BLAS-3) instead of a Householder QR, about 10x cheaper for the tall
    blocks here. Its Cholesky factor with complete pivoting (LAPACK pstrf), P^T B^T B P = U^T U, stops at the
    rank of A (the remaining pivots below RANK_TOLERANCE times K, a bound of B^T B's largest eigenvalue):
    R = U P^T D, exact for rank-deficient A
    (a block's rows seldom see every direction of its keys; directions with no information get zero rows);
    the factorisation is about 10x faster than an eigen-decomposition of the same matrix."""
    k = A.shape[1]
    gram = A.T @ A
    scale = np.sqrt(np.diagonal(gram))  # the column norms
    scale[scale == 0] = 1.0
    factor, pivots, rank, _ = scipy.linalg.lapack.dpstrf(gram / np.outer(scale, scale), tol=RANK_TOLERANCE * k,
                                                         lower=0)  # B^T B
    order = pivots - 1  # the columns in pivoted order
    U = np.triu(factor[:rank])  # rank x K
    z, R = np.zeros(k + 1), np.zeros((k + 1, k))
    if rank:
        Btr = (A.T @ r) / scale
        z[:rank] = scipy.linalg.solve_triangular(U[:, :rank], Btr[order[:rank]], trans="T", check_finite=False)
        R[:rank, order] = U * scale[order]
    z[k] = np.sqrt(max(float(r @ r - z @ z), 0.0))
    return z, R


RANK_TOLERANCE = 1e-13  # a Cholesky pivot below this times the matrix's size ends the rank


def _error(block: Block, compressed: bool, this: gtsam.CustomFactor, values: gtsam.Values, H) -> np.ndarray:
    if compressed and H is None:  # cost only: any vector with the same norm will do
        r, _ = residuals(block, values, jacobians=False)
        out = np.zeros(sum(block.widths.values()) + 1)
        out[0] = np.linalg.norm(r)
        return out
    r, A = residuals(block, values, jacobians=H is not None)
    if H is None:
        return r
    if compressed:
        r, A = compress(r, A)
    for index, J in enumerate(jacobian_by_key(block, A).values()):
        H[index] = np.asfortranarray(J)
    return r


def make_factor(block: Block, compressed: bool = True,
                robust: gtsam.noiseModel.mEstimator.Base | None = None) -> gtsam.CustomFactor:
    """The block as one CustomFactor. compressed: the residual compressed to one row per Jacobian
    column plus one (see compress; needs N >= total key dimension and no robust loss). robust: an mEstimator created with ReweightScheme.Scalar,
    applied row by row to the stacked residual."""
    width = sum(block.widths.values())
    if compressed and robust is not None:
        raise ValueError("a robust loss needs the stacked residual (compressed=False)")
    if compressed and len(block) < width:
        compressed = False  # too few rows to compress: stack them
    noise = gtsam.noiseModel.Unit.Create(width + 1 if compressed else len(block))
    if robust is not None:
        noise = gtsam.noiseModel.Robust.Create(robust, noise)
    return gtsam.CustomFactor(noise, list(block.widths), partial(_error, block, compressed))
