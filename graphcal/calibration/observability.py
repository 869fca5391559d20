"""1-sigma of every estimated parameter from gtsam.Marginals (which parameters the data cannot see:
weak_directions.py).

The graph's cost is (W / sigma0^2) J + priors, so the marginal covariances are those of a
least-squares fit with point noise sigma0 (Cramér-Rao bound when sigma0 is the true noise).
"""

from __future__ import annotations

import copy
import itertools
from dataclasses import dataclass, replace

import gtsam
import numpy as np
import scipy.linalg
import scipy.sparse as sparse
import scipy.sparse.linalg
from threadpoolctl import threadpool_limits

from graphcal.common.cluster import usable_cores
from graphcal.recording.intrinsics import offsets_to_file_units

POSE_TO_FILE_UNITS = np.r_[np.full(3, np.degrees(1.0)), np.ones(3)]  # [rad x3, m x3] -> [deg x3, m x3]
INTRINSIC_NAMES = ("d_range_m", "d_azimuth_deg", "d_elevation_deg", "h_z_m")
EXTRINSIC_NAMES = ("roll_deg", "pitch_deg", "yaw_deg", "lever_arm_x_m", "lever_arm_y_m", "lever_arm_z_m")
TRAJECTORY_GAUGE = ("trajectory.common_translation", "trajectory.common_rotation")
CONTROL_NAMES = ("rotation_x_deg", "rotation_y_deg", "rotation_z_deg", "x_m", "y_m", "z_m")
# share of a parameter's prior variance in the weak directions held at nominal above which it is named unobservable
# (weak_directions.py)
NAMED_SHARE = 0.25


def parameter_at(name: str) -> tuple[str, int, int]:
    """Where a parameter named fibre_<i>.<intrinsic>, extrinsic.<axis> or control_<c>.<component> sits: its group
    ("intrinsics", "extrinsic", "controls"), its row (the fibre, the control; 0 for the extrinsic) and its column
    (in INTRINSIC_NAMES, EXTRINSIC_NAMES, CONTROL_NAMES)."""
    owner, parameter = name.split(".")
    if owner.startswith("fibre_"):
        return "intrinsics", int(owner[6:]), INTRINSIC_NAMES.index(parameter)
    if owner == "extrinsic":
        return "extrinsic", 0, EXTRINSIC_NAMES.index(parameter)
    return "controls", int(owner.split("_")[1]), CONTROL_NAMES.index(parameter)


def shown(name: str, value: float) -> str:
    """A value of the parameter `name` (in its file unit, the name's suffix: _m or _deg) as a user reads it: metres in
    cm, degrees as they are."""
    return f"{value * 100:.3g} cm" if name.endswith("_m") else f"{value:.3g} deg"


def intrinsic_mask(names, n_fibres: int) -> np.ndarray:
    """(n_fibres, 4) True where fibre_i.<intrinsic> is among the names (any other name is passed over)."""
    mask = np.zeros((n_fibres, 4), bool)
    for name in names:
        owner, _, parameter = name.partition(".")
        if owner.startswith("fibre_") and parameter in INTRINSIC_NAMES:
            mask[parameter_at(name)[1:]] = True
    return mask


@dataclass(frozen=True)
class Uncertainty:
    """Posterior and prior 1-sigma per parameter, in the file units of each name (m or deg):
    intrinsics (n_fibres, 4), NaN where not estimated; extrinsic (6,) as rotation about body
    x/y/z then lever arm in body axes, or None; control corrections (C, 6) as rotation about
    world x/y/z then translation (rotation columns NaN for translation-only), or None."""

    intrinsics: np.ndarray
    intrinsics_prior: np.ndarray
    extrinsic: np.ndarray | None
    extrinsic_prior: np.ndarray | None
    controls: np.ndarray | None
    controls_prior: np.ndarray | None

    def widest(self, other: Uncertainty) -> Uncertainty:
        """Each posterior sigma the larger of this one's and other's (same parameters, same priors)."""
        def wider(a, b):
            return None if a is None else np.fmax(a, b)

        return replace(self, intrinsics=wider(self.intrinsics, other.intrinsics),
                       extrinsic=wider(self.extrinsic, other.extrinsic), controls=wider(self.controls, other.controls))

    def with_nominal_held(self, shares: dict[str, float]) -> Uncertainty:
        """These sigmas where a part of a parameter's prior variance is held at its nominal value (shares: {name: s},
        s in [0, 1] its share of prior variance in the directions held, WeakDirections.held_shares): at least sqrt(s)
        times its prior sigma, since along those directions its value is the nominal's, whose error is the prior's
        whatever the data add along the rest, where the final fit's marginals (the lock left out) give the data's
        sigma along them, down to a third of the prior's; and, once named (s above NAMED_SHARE), at most its prior
        sigma, since along the rest the data see it at least ten times better than the prior, where a sandwich's
        scatter pushed through H^-1 along the held directions can exceed the prior's. A held axis alone (s = 1) has
        its prior's sigma."""
        intrinsics = self.intrinsics.copy()
        extrinsic = None if self.extrinsic is None else self.extrinsic.copy()
        for name, share in shares.items():
            group, row, column = parameter_at(name)
            if group == "intrinsics":
                sigmas, at, prior = intrinsics, (row, column), self.intrinsics_prior[row, column]
            elif group == "extrinsic" and extrinsic is not None:
                sigmas, at, prior = extrinsic, column, self.extrinsic_prior[column]
            else:
                continue
            upper = prior if share > NAMED_SHARE else np.inf
            sigmas[at] = np.clip(sigmas[at], np.sqrt(share) * prior, upper)  # NaN (not estimated) stays NaN
        return replace(self, intrinsics=intrinsics, extrinsic=extrinsic)

    def without(self, held: set[str]) -> Uncertainty:
        """These sigmas with NaN for the named parameters (held at nominal: not estimated, no sigma to report)."""
        intrinsics = self.intrinsics.copy()
        extrinsic = None if self.extrinsic is None else self.extrinsic.copy()
        controls = None if self.controls is None else self.controls.copy()
        for name in held:  # a group not estimated (None) has no sigma to hide
            group, row, column = parameter_at(name)
            if group == "intrinsics":
                intrinsics[row, column] = np.nan
            elif group == "extrinsic" and extrinsic is not None:
                extrinsic[column] = np.nan
            elif group == "controls" and controls is not None:
                controls[row, column] = np.nan
        return replace(self, intrinsics=intrinsics, extrinsic=extrinsic, controls=controls)


def reported(model: Uncertainty, shared_returns: Uncertainty | None, cluster_robust: Uncertainty | None,
             held_shares: dict[str, float] | None = None) -> Uncertainty:
    """The 1-sigmas a calibration reports: with each return's noise counted once when computed (shared_returns), else
    the model's, each widened to the cluster-robust sigma where that is larger (the residuals vary more than their
    model), and bounded where the weak directions hold a share of a parameter at its nominal value (held_shares:
    {name: share}, WeakDirections.held_shares; Uncertainty.with_nominal_held)."""
    modelled = model if shared_returns is None else shared_returns
    widest = modelled if cluster_robust is None else modelled.widest(cluster_robust)
    return widest.with_nominal_held(held_shares or {})


class Meat:
    """A sandwich's meat over the information matrix's columns, never a dense n x n but where it is as dense as
    DENSE_FROM (a drive that comes back often ties most controls together): a sparse symmetric matrix plus factors,
    matrix + sum_i weight_i Z_i^T Z_i (Z_i: rows x columns, sparse or dense), each kept as it is given (a factor
    of few rows, as time blocks' scores, costs less than its product). Summed first, then multiplied."""

    def __init__(self, matrix=None, factors: tuple = ()):
        self.matrix = None if matrix is None else sparse.csr_matrix(matrix)
        self.factors = tuple(factors)  # (Z, weight)

    def __add__(self, other: Meat) -> Meat:
        matrices = [m for m in (self.matrix, other.matrix) if m is not None]
        return Meat(sum(matrices[1:], matrices[0]) if matrices else None, self.factors + other.factors)

    def times(self, X: np.ndarray) -> np.ndarray:
        """meat @ X for X (columns, k) dense."""
        if sparse.issparse(self.matrix) and as_dense_as(self.matrix.nnz, self.matrix.shape):
            self.matrix = self.matrix.toarray()  # a dense product is several times faster than a sparse one there
        out = np.zeros_like(X) if self.matrix is None else self.matrix @ X
        for Z, weight in self.factors:
            out += weight * (Z.T @ (Z @ X))
        return out


class FactorisedMarginals:
    """Marginal covariances of the graph linearised at values, from its information matrix H (the priors'
    included, assembled sparse) factorised once (ScaledSolver): each block asked for is solved for and H^-1 is never
    made whole, nor the sandwiches' products (Meat), so that the memory holds one factor of H (sparse where H is
    sparse) beside a few chunks of columns, where the whole inverses would hold several n x n (130 + 6 per
    trajectory control: an hour's drive, 3 601 controls, 1 GB per dense copy). Same interface as gtsam.Marginals
    (marginalCovariance(key)); the fallback when gtsam.Marginals' Cholesky calls a graph "indeterminate" because
    its information spans many orders of magnitude (millimetre-sharp intrinsics next to a lever arm held only by
    its 1 m prior), and the bread of the sandwich covariances (sandwich)."""

    def __init__(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values):
        widths = tangent_widths(values)
        self._of(information_of(graph, values, widths), widths)

    @classmethod
    def of(cls, information, widths: dict[int, int]) -> FactorisedMarginals:
        """The marginals of an information matrix (dense or sparse) whose columns are the keys' tangent spaces, in
        order."""
        out = cls.__new__(cls)
        out._of(sparse.csc_matrix(information), widths)
        return out

    def _of(self, information: sparse.csc_matrix, widths: dict[int, int]) -> None:
        self._information = information
        self.solve = ScaledSolver(information)
        self._meat = None  # a sandwich's Meat: its covariance is H^-1 meat H^-1
        self._added = {}  # {key: covariance added to its tangent block} (widened)
        self._marginals = {}  # {key: its marginal block}, made a chunk of keys at a time
        self._span = {key: slice(start, start + widths[key]) for key, start in first_columns(widths).items()}

    def marginalCovariance(self, key) -> np.ndarray:
        if key not in self._marginals:
            self._marginals = self._chunk_from(key)
        block = self._marginals[key]
        return block + self._added[key] if key in self._added else block

    @property
    def width(self) -> int:
        """Columns of the information matrix: every key's tangent space."""
        return self._information.shape[0]

    @property
    def widths(self) -> dict[int, int]:
        """Each key's tangent dimension, in the order of the information matrix's columns."""
        return {key: span.stop - span.start for key, span in self._span.items()}

    def columns(self) -> dict[int, int]:
        """Each key's first column in the information matrix."""
        return {key: span.start for key, span in self._span.items()}

    def columns_of(self, key) -> np.ndarray:
        """The key's columns in the information matrix (its tangent coordinates, in order)."""
        return np.arange(self._span[key].start, self._span[key].stop)

    def jointCovariance(self, a, b) -> np.ndarray:
        """The covariance block of keys a (rows) and b (columns)."""
        if a == b:
            return self.marginalCovariance(a)
        of_a = self.rows(self.columns_of(a))
        if self._meat is None:
            return of_a[:, self._span[b]]
        return of_a @ self._meat.times(self.rows(self.columns_of(b)).T)

    def rows(self, columns: np.ndarray) -> np.ndarray:
        """(len(columns), width) the given rows of H^-1 (not a sandwich's, nor widened)."""
        return self.solve.inverse_columns(columns).T

    @property
    def information(self) -> sparse.csc_matrix:
        """H, the sparse information matrix (the priors' included), in the columns of columns()."""
        return self._information

    def widened(self, added: dict[int, np.ndarray]) -> FactorisedMarginals:
        """These marginals with added[key] (width x width) added to each given key's block."""
        out = copy.copy(self)
        out._added = {**self._added, **{key: self._added.get(key, 0.0) + v for key, v in added.items()}}
        return out

    def sandwich(self, meat: Meat) -> FactorisedMarginals:
        """The marginals of H^-1 meat H^-1 (a sandwich covariance on the same keys)."""
        out = copy.copy(self)
        out._meat, out._marginals = meat, {}
        return out

    def _chunk_from(self, key) -> dict:
        """{key: marginal block} for key and the keys after it, up to CHUNK_COLUMNS columns of H^-1 solved at once."""
        keys = list(self._span)
        chunk, columns = [], 0
        for k in keys[keys.index(key):]:
            if chunk and columns + len(self.columns_of(k)) > CHUNK_COLUMNS:
                break
            chunk.append(k)
            columns += len(self.columns_of(k))
        wanted = np.concatenate([self.columns_of(k) for k in chunk])
        solved = self.rows(wanted).T  # (width, chunk's columns) H^-1's columns
        pushed = solved if self._meat is None else self._meat.times(solved)
        out, start = {}, 0
        for k in chunk:
            local = slice(start, start + len(self.columns_of(k)))
            out[k] = solved[self._span[k], local] if self._meat is None else solved[:, local].T @ pushed[:, local]
            start = local.stop
        return out


CHUNK_COLUMNS = 512  # columns of H^-1 solved for at once (an hour's drive: 11 k rows, 45 MB)


class ScaledSolver:
    """x = H^-1 b for a symmetric positive semi-definite information matrix H (sparse), scaled to a unit diagonal
    first: H spans far more than 1/eps between parameters, but mostly through their units and priors, which the
    scaling takes out. By a Cholesky factor of the scaled matrix where its pivots stay above WELL_CONDITIONED:
    sparse (SuperLU in symmetric mode: a minimum-degree order of H, no pivoting, so H = L D L^T) unless H or its
    factor is as dense as DENSE_FROM (a drive that comes back often ties most controls together, and a sparse
    solve is then ten times slower than a dense one; an ndarray is taken dense), else dense, turned into the
    inverse in place (one n x n, multiplied by b; inverse=False: the factor kept, b solved by it). Where the pivots
    vanish, by the dense eigen-decomposition with the eigenvalues floored at eps times the largest (a nearly
    singular H: its near-null directions get variances of 1/floor instead of infinities)."""

    def __init__(self, information, inverse: bool = True):
        given_dense = isinstance(information, np.ndarray)  # an ndarray is factorised dense (a copy of it)
        information = information if given_dense else sparse.csc_matrix(information)
        self._scale = 1.0 / np.sqrt(information.diagonal())
        self._inverse = None  # the scaled inverse's lower triangle, where it is made dense
        try:
            sparse_enough = not given_dense and not as_dense_as(information.nnz, information.shape)
            self._solve = (sparse_enough and self._sparse_factor(information)) or self._dense(information, inverse)
            self.factorised = True
        except (np.linalg.LinAlgError, RuntimeError):  # RuntimeError: SuperLU's exactly singular pivot
            eigenvalues, vectors = np.linalg.eigh(self._scaled(information))
            floored = np.maximum(eigenvalues, eigenvalues.max() * np.finfo(float).eps)
            self._solve, self.factorised = lambda b: (vectors / floored) @ (vectors.T @ b), False

    def __call__(self, b: np.ndarray) -> np.ndarray:
        scale = self._scale[:, None] if np.ndim(b) == 2 else self._scale
        return scale * self._solve(np.ascontiguousarray(scale * b))

    def inverse_columns(self, columns: np.ndarray) -> np.ndarray:
        """(n, len(columns)) the given columns of H^-1: read off the inverse where it is held, else solved for."""
        columns = np.asarray(columns)
        if self._inverse is None:
            unit = np.zeros((len(self._scale), len(columns)))
            unit[columns, np.arange(len(columns))] = 1.0
            return self(unit)
        below = np.arange(len(self._scale))[:, None] >= columns[None, :]  # the lower triangle holds those
        scaled = np.where(below, self._inverse[:, columns], self._inverse[columns, :].T)
        return self._scale[:, None] * scaled * self._scale[columns][None, :]

    def _scaled(self, information) -> np.ndarray:
        """The unit-diagonal matrix, dense (a copy), scaled in place."""
        scaled = information.toarray() if sparse.issparse(information) else np.array(information)
        scaled *= self._scale[:, None]
        scaled *= self._scale[None, :]
        return scaled

    def _dense(self, information, inverse: bool):
        """The scaled matrix's Cholesky factor made in place over it (LAPACK potrf: one n x n, its lower triangle),
        solving by it (inverse False), or turned into the inverse in place (potri), solving by a symmetric product."""
        scaled = self._scaled(information).T  # symmetric: the transposed view is Fortran-ordered, factorised in place
        factor, info = scipy.linalg.lapack.dpotrf(scaled, lower=1, clean=0, overwrite_a=1)
        if info != 0 or np.min(np.diag(factor)) ** 2 < WELL_CONDITIONED:
            raise np.linalg.LinAlgError("pivots near rounding")
        if not inverse:
            return lambda b: scipy.linalg.lapack.dpotrs(factor, b, lower=1)[0]
        inverse, info = scipy.linalg.lapack.dpotri(factor, lower=1, overwrite_c=1)
        if info != 0:
            raise np.linalg.LinAlgError("a pivot at zero")
        self._inverse = inverse
        return lambda b: scipy.linalg.blas.dsymm(1.0, inverse, b.reshape(len(b), -1), lower=1).reshape(b.shape)

    def _sparse_factor(self, information: sparse.csc_matrix):
        scaled = sparse.csc_matrix(sparse.diags(self._scale) @ information @ sparse.diags(self._scale))
        factor = scipy.sparse.linalg.splu(scaled, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                                          options={"SymmetricMode": True})
        if not np.min(factor.U.diagonal()) >= WELL_CONDITIONED:
            raise np.linalg.LinAlgError("pivots near rounding")
        filled_in = as_dense_as(factor.L.nnz, information.shape, 0.5)  # L: a triangle
        return None if filled_in else factor.solve


def tangent_widths(values: gtsam.Values) -> dict[int, int]:
    """{key: the dimension of its tangent space}, in the values' order (GTSAM's: sorted keys)."""
    zero = values.zeroVectors()
    return {key: zero.at(key).size for key in values.keys()}


def first_columns(widths: dict[int, int]) -> dict[int, int]:
    """{key: its first column} when the keys' tangent spaces follow one another in widths' order."""
    return dict(zip(widths, np.r_[0, np.cumsum(list(widths.values()))[:-1]].tolist()))


def columns_of_keys(starts: dict[int, int], widths: dict[int, int], keys) -> np.ndarray:
    """The columns of the given keys' tangent spaces, in the keys' order (starts: first_columns(widths))."""
    return np.concatenate([starts[key] + np.arange(widths[key]) for key in keys] or [np.zeros(0, int)])


def as_dense_as(nonzeros: int, shape: tuple[int, int], fraction: float = 1.0) -> bool:
    """Whether nonzeros fill fraction x DENSE_FROM of a matrix of that shape (held and factorised dense from there)."""
    return nonzeros >= fraction * DENSE_FROM * np.prod(shape)


def information_of(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, widths: dict[int, int],
                   factors: range | None = None, augmented: bool = False, dense: bool = False):
    """H at values, the sum of the graph's factors' (or of the given factors') information, each scattered into
    its keys' columns (the keys in widths' order), sparse (dense: an ndarray, summed in place); augmented:
    [H g; g^T f] (n + 1 columns), g = A^T b the right-hand side of the Gauss-Newton step H dx = g (gtsam's
    augmentedInformation). Linearised a batch of factors at a time (factor_information); sparse, each batch's
    sum is merged with the others pairwise as a binary counter (each entry is summed about log(batches) times,
    not once per batch)."""
    width = sum(widths.values()) + augmented
    if dense:
        total = np.zeros((width, width))
        for columns, information in factor_information(graph, values, widths, factors, augmented):
            total[np.ix_(columns, columns)] += information
        return total
    sums = []  # (batches summed, their sum): sizes decreasing as the bits of a binary counter
    pieces = factor_information(graph, values, widths, factors, augmented)
    while batch := list(itertools.islice(pieces, FACTORS_PER_BATCH)):
        rows = np.concatenate([np.repeat(columns, len(columns)) for columns, _ in batch])
        cols = np.concatenate([np.tile(columns, len(columns)) for columns, _ in batch])
        entries = np.concatenate([information.ravel() for _, information in batch])
        total = (1, sparse.csc_matrix((entries, (rows, cols)), shape=(width, width)))
        while sums and sums[-1][0] == total[0]:
            count, summed = sums.pop()
            total = (count + total[0], summed + total[1])
        sums.append(total)
    return sum((summed for _, summed in sums[1:]), sums[0][1]) if sums else sparse.csc_matrix((width, width))


def factor_information(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, widths: dict[int, int],
                       factors: range | None = None, augmented: bool = False):
    """(columns, information) of each of the graph's factors (or of the given ones) at values, its keys' columns
    in widths' order (augmented: the augmented information, its last column n). Linearised FACTORS_PER_BATCH at
    a time: the linear factors held stay bounded (a drive's thousands of blocks each hold a dense compressed
    Jacobian)."""
    starts = first_columns(widths)
    last = np.array([sum(widths.values())] if augmented else [], int)
    factors = range(graph.size()) if factors is None else factors
    for first in range(factors.start, factors.stop, FACTORS_PER_BATCH):
        batch = gtsam.NonlinearFactorGraph()
        for index in range(first, min(first + FACTORS_PER_BATCH, factors.stop)):
            batch.add(graph.at(index))
        linear = batch.linearize(values)
        for i in range(linear.size()):
            factor = linear.at(i)
            columns = np.concatenate([columns_of_keys(starts, widths, factor.keys()), last])
            yield columns, factor.augmentedInformation() if augmented else factor.information()


def key_density(graph: gtsam.NonlinearFactorGraph, widths: dict[int, int]) -> float:
    """The fraction of H's entries (the keys' tangent columns, widths' order) the graph's factors reach: the
    columns of every pair of keys some factor joins."""
    index = {key: k for k, key in enumerate(widths)}
    width = np.array(list(widths.values()), float)
    if not graph.size() or not widths:
        return 0.0
    rows, cols = [], []
    for i in range(graph.size()):
        keys = np.array([index[key] for key in graph.at(i).keys() if key in index], np.int64)
        rows.append(np.repeat(keys, len(keys)))
        cols.append(np.tile(keys, len(keys)))
    pattern = sparse.csr_matrix((np.ones(sum(len(r) for r in rows)), (np.concatenate(rows), np.concatenate(cols))),
                                shape=(len(widths), len(widths)))
    pattern.data[:] = 1.0  # duplicates summed: each pair once
    return float(width @ (pattern @ width)) / width.sum() ** 2


def schur_complement(H: np.ndarray, widths: dict[int, int], keys: list[int]) -> np.ndarray:
    """H_kk - H_ko H_oo^-1 H_ok: the information on the given keys (their columns in keys' order) of a dense H over
    every key of widths (in widths' order), the other keys (o) eliminated; by LAPACK's Cholesky of H_oo on every
    core (ScaledSolver). H is left as it was."""
    kept = columns_of_keys(first_columns(widths), widths, keys)
    others = np.setdiff1d(np.arange(len(H)), kept)
    coupling = H[np.ix_(others, kept)]
    with every_core():
        solved = ScaledSolver(H[np.ix_(others, others)], inverse=False)(coupling)
    return H[np.ix_(kept, kept)] - coupling.T @ solved


def every_core():
    """BLAS on every core the process may use (the calibration holds it to one around the block factors'
    callbacks), for a large dense factorisation."""
    return threadpool_limits(limits=usable_cores(), user_api="blas")


def assembled_dense(graph: gtsam.NonlinearFactorGraph, widths: dict[int, int]) -> bool:
    """Whether a graph's system is solved assembled dense rather than by GTSAM's elimination: LARGE_FROM columns
    or more, DENSE_FROM of H reached by its factors (key_density). A long drive's passes tie most trajectory keys
    together, and GTSAM's multifrontal elimination of such a system (Eigen's kernels, one core) grows as the cube
    of the keys: on city_loop at the truth, 1 933 columns (ten minutes) 1.6 s an elimination against 0.13 s for
    LAPACK's Cholesky of the dense H; 10 933 (an hour) two Levenberg-Marquardt iterations 475 s against 45 s."""
    return sum(widths.values()) >= LARGE_FROM and key_density(graph, widths) >= DENSE_FROM


DENSE_FROM = 0.05  # fraction of nonzeros from which a matrix is held and factorised dense
LARGE_FROM = 3000  # columns from which a graph DENSE_FROM dense is assembled dense and factorised by LAPACK
FACTORS_PER_BATCH = 200  # factors linearised and summed at once (blocks of 232 columns: 260 MB of triplets)
WELL_CONDITIONED = 1e-10  # the smallest squared Cholesky pivot (LDL^T) of a unit-diagonal matrix solved by its factor


class Marginals:
    """gtsam.Marginals, switching to FactorisedMarginals for every key once GTSAM finds the system
    nearly indeterminate (in its constructor, or lazily when a covariance is asked for)."""

    def __init__(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values):
        self._graph, self._values = graph, values
        try:
            self._marginals = gtsam.Marginals(graph, values)
        except RuntimeError as error:
            self._marginals = self._solved_after(error)

    def marginalCovariance(self, key) -> np.ndarray:  # gtsam.Marginals' name
        try:
            return self._marginals.marginalCovariance(key)
        except RuntimeError as error:  # FactorisedMarginals never raises it: this switches once
            self._marginals = self._solved_after(error)
            return self._marginals.marginalCovariance(key)

    def _solved_after(self, error: RuntimeError) -> FactorisedMarginals:
        if "Indeterminate" not in str(error):
            raise error
        return FactorisedMarginals(self._graph, self._values)


def intrinsic_sigmas(marginals: gtsam.Marginals, key) -> np.ndarray:
    """(4,) sigmas of a Vector4 intrinsic key in file units (m, deg, deg, m)."""
    return offsets_to_file_units(np.sqrt(np.diag(marginals.marginalCovariance(key))))


def tangent_to_axes(R: np.ndarray) -> np.ndarray:
    """(6, 6) map of a Pose3 tangent [w, v] into the axes of R's output frame: GTSAM's retract
    perturbs R Exp(w), t + R v, so both parts turn by R (e.g. lidar -> body for T_body_lidar)."""
    rotate = np.zeros((6, 6))
    rotate[:3, :3] = rotate[3:, 3:] = R
    return rotate


def pose_sigmas(covariance_tangent: np.ndarray, R: np.ndarray) -> np.ndarray:
    """(6,) sigmas [deg x3, m x3] of a Pose3 whose tangent covariance is given, in the axes of
    R's output frame (see tangent_to_axes)."""
    rotate = tangent_to_axes(R)
    return np.sqrt(np.diag(rotate @ covariance_tangent @ rotate.T)) * POSE_TO_FILE_UNITS


TIE = 0.05  # relative: softest-direction components this close to the largest are a tie


def soft_parameters(information: np.ndarray, firm_sigma: np.ndarray) -> list[int]:
    """Indices of the parameters to hold so that every remaining one, and every combination of
    them, is determined to within firm_sigma by the data: the smallest eigenvalue of the
    information whitened by firm_sigma (information * outer(firm_sigma, firm_sigma)) is then
    at least 1. Greedy and pivoted: while the free set has a softer direction, hold the free
    parameter with the largest component along the softest direction (for a direction no pair
    sees, e.g. the common vertical offset of fibres that never pair with the reference fibre,
    this picks one of them, as choosing a reference fixes a gauge). Components within TIE of the
    largest are a tie, which the first of them wins: a common mode's components are equal up to
    rounding, and which one argmax found flipped the static halves check.

    information: (P, P) Gauss-Newton information of the data term (units of the parameters^-2);
    firm_sigma: (P,) the largest 1-sigma that counts as determined, in the parameters' units."""
    whitened = np.asarray(information, dtype=np.float64) * np.outer(firm_sigma, firm_sigma)
    free = list(range(len(firm_sigma)))
    held = []
    while free:
        eigenvalues, vectors = np.linalg.eigh(whitened[np.ix_(free, free)])
        if eigenvalues[0] >= 1.0:
            break
        component = np.abs(vectors[:, 0])
        held.append(free.pop(int(np.argmax(component >= (1.0 - TIE) * component.max()))))
    return sorted(held)
