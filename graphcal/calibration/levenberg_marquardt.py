"""Levenberg-Marquardt on a calibration's factor graph: GTSAM's optimizer, or, for a graph of many keys nearly
dense (observability.assembled_dense: a long drive whose passes tie most trajectory keys together), the same
algorithm with each linearisation assembled dense and factorised by LAPACK."""

from __future__ import annotations

import gtsam
import numpy as np

from graphcal.calibration.observability import (ScaledSolver, assembled_dense, every_core, first_columns,
                                                information_of, tangent_widths)

# Levenberg-Marquardt's damping bound: the Hessian's diagonal spans from held priors (1/HELD_SIGMA^2 = 1e14)
# to loose ones
LAMBDA_UPPER_BOUND = 1e12
# GTSAM's defaults (LevenbergMarquardtParams), which the assembled variant follows
LAMBDA_INITIAL, LAMBDA_FACTOR = 1e-5, 10.0
MIN_DIAGONAL, MAX_DIAGONAL = 1e-6, 1e32  # the Hessian's diagonal, clipped, scales the damping
MIN_MODEL_FIDELITY = 1e-3  # a step is taken when the cost falls by this fraction of what the linear model predicts
RELATIVE_ERROR_TOL = ABSOLUTE_ERROR_TOL = 1e-5


def levenberg_marquardt(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, iterations: int,
                        assembled: bool | None = None) -> gtsam.Values:
    """Levenberg-Marquardt with damping scaled by the Hessian's diagonal, at most `iterations` linearisations.
    With GTSAM's default (lambda times the identity, lambda <= 1e5) a graph whose diagonal reaches 1e14 (a held
    parameter beside millimetre-sharp ones) gets Gauss-Newton steps whatever lambda, and when that step overshoots
    LM rejects every lambda and returns the values unchanged: measured on diagnose's refit with a pitched head
    (time offset stuck at 0, with this damping 5.14 ms for a true 5 ms). assembled (None: assembled_dense, a large
    graph nearly dense) by assembled_levenberg_marquardt; else (a drive over new ground: sparse) by GTSAM's."""
    widths = tangent_widths(values)
    if assembled or (assembled is None and assembled_dense(graph, widths)):
        return assembled_levenberg_marquardt(graph, values, iterations, widths)
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(iterations)
    params.setDiagonalDamping(True)
    params.setlambdaUpperBound(LAMBDA_UPPER_BOUND)
    return gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()


def assembled_levenberg_marquardt(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, iterations: int,
                                  widths: dict[int, int] | None = None) -> gtsam.Values:
    """GTSAM's Levenberg-Marquardt (diagonal damping, lambda from LAMBDA_INITIAL divided or multiplied by
    LAMBDA_FACTOR, a step taken when the cost falls by MIN_MODEL_FIDELITY of the linear model's prediction, no
    step once the cost's change is below RELATIVE_ERROR_TOL of it, stopped by the relative or absolute tolerance)
    with each linearisation assembled as a dense [H g] (observability.information_of) and each damped system
    H + lambda diag(H) solved by LAPACK's Cholesky (ScaledSolver) on every core."""
    widths = tangent_widths(values) if widths is None else widths
    error, lam = graph.error(values), LAMBDA_INITIAL
    for _ in range(iterations):
        system = information_of(graph, values, widths, augmented=True, dense=True)
        n = system.shape[0] - 1
        H, g = system[:n, :n], system[:n, n].copy()
        damping = np.clip(H.diagonal(), MIN_DIAGONAL, MAX_DIAGONAL)
        while True:
            delta = _solved(H, lam * damping, g)
            predicted = float(delta @ g - 0.5 * delta @ (H @ delta))  # the linear model's fall of the cost
            taken = stop = False
            if predicted >= 0:
                candidate = values.retract(_vector_values(delta, widths))
                new_error = graph.error(candidate)
                change = error - new_error
                taken = predicted > np.finfo(float).eps * 0.5 * float(system[n, n]) and \
                    change / predicted > MIN_MODEL_FIDELITY
                stop = abs(change) < RELATIVE_ERROR_TOL * error
            if taken:
                values, previous, error, lam = candidate, error, new_error, lam / LAMBDA_FACTOR
                break
            lam *= LAMBDA_FACTOR
            if stop or lam >= LAMBDA_UPPER_BOUND:
                return values
        if previous - error <= max(RELATIVE_ERROR_TOL * previous, ABSOLUTE_ERROR_TOL):
            break
    return values


def _solved(H: np.ndarray, added: np.ndarray, g: np.ndarray) -> np.ndarray:
    """(H + diag(added))^-1 g, BLAS on every core; H is left as it was."""
    diagonal = np.einsum("ii->i", H)  # a view of H's diagonal
    undamped = diagonal.copy()
    diagonal += added
    try:
        with every_core():
            return ScaledSolver(H, inverse=False)(g)
    finally:
        diagonal[:] = undamped


def _vector_values(delta: np.ndarray, widths: dict[int, int]) -> gtsam.VectorValues:
    """The tangent step of each key (widths' order) as GTSAM's VectorValues."""
    out = gtsam.VectorValues()
    for key, start in first_columns(widths).items():
        out.insert(key, delta[start:start + widths[key]])
    return out
