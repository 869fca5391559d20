"""Trajectory corrections the data do not see: stretches of the drive with too little structure.

A control correction moves the returns of the control intervals on each side of its time (eq. 5.1's interpolation);
the pairs among them see it along the normals of the surfaces they lie on. Where the drive crosses an open field, a
featureless road or a gap in the recording, those pairs pin the correction along few directions (the ground's
normal alone: its height) or none, and E_def holds it there: the seed's prior of no correction (eq. 5.3) or
Monnier's differences, which carry the neighbouring controls' corrections across the stretch. Measured by the
posterior sigma of each component with the data's information on each control (every other key held:
Problem.control_information) and E_def's terms, the controls' chain solved as one sparse system: a component known
no better than the range noise the pairs are whitened by (weighting.sigma0_m) is named. Under Monnier's differences
a stretch of k controls the data do not see is known to about sigma sqrt(k / 4) in its middle (sigma: E_def's
term), so a short gap between two seen streets is not named and a long one is; a thinly sampled drive whose every
control sees a little is not named either, since the chain pools what its controls see.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

from graphcal.calibration.observability import CONTROL_NAMES

CHUNK_COLUMNS = 1024  # columns of the inverse solved at once: CHUNK_COLUMNS x 8 bytes per key's column of memory


def posterior_sigmas(information: np.ndarray, sigma_m: float, deformation: Literal["prior", "monnier"]) -> np.ndarray:
    """(C, d) posterior sigma [m, or rad x 1 m] of each component of each control correction, from the data's
    information on each control (C, d, d) [m^-2] and E_def's terms of sigma_m: a prior on each control (eq. 5.3)
    or each successive difference, with a prior of sigma_m sqrt(C) on each control (monnier)."""
    controls, width = information.shape[:2]
    n = controls * width
    data = scipy.sparse.block_diag([0.5 * (block + block.T) for block in information], format="csr")
    if deformation == "prior":
        rigidity = scipy.sparse.identity(n, format="csr")
    else:
        ones = np.ones(controls - 1)
        steps = scipy.sparse.diags([ones, -ones], [0, 1], shape=(controls - 1, controls))
        chain = (steps.T @ steps + scipy.sparse.identity(controls) / controls).tocsr()
        rigidity = scipy.sparse.kron(chain, scipy.sparse.identity(width), format="csr")
    factor = scipy.sparse.linalg.splu((data + rigidity / sigma_m ** 2).tocsc())
    variance = np.empty(n)
    for start in range(0, n, CHUNK_COLUMNS):
        columns = np.arange(start, min(start + CHUNK_COLUMNS, n))
        unit = np.zeros((n, len(columns)))
        unit[columns, np.arange(len(columns))] = 1.0
        variance[columns] = factor.solve(unit)[columns, np.arange(len(columns))]
    return np.sqrt(variance).reshape(controls, width)


def unseen_controls(information: np.ndarray, control_times_s: np.ndarray, sigma_m: float,
                    deformation: Literal["prior", "monnier"], threshold_m: float) -> dict[str, str]:
    """{control_<c>.<component>: reason} for the components of the control corrections known no better than
    threshold_m [m, or rad x 1 m] (posterior_sigmas); information (C, d, d) [m^-2] from Problem.control_information
    (d: 6, rotation then translation, or 3), control times [s] of the recording's clock, E_def's term sigma_m."""
    names = CONTROL_NAMES[-information.shape[1]:]
    sigmas = posterior_sigmas(information, sigma_m, deformation)
    rigidity = "its prior (eq. 5.3)" if deformation == "prior" else "the neighbouring controls (Monnier's differences)"
    reasons = {}
    for c, sigma in enumerate(sigmas):
        unseen = sigma > threshold_m
        seen = [name for name, hidden in zip(names, unseen) if not hidden]
        for name, value in zip(names, sigma):
            if value > threshold_m:
                reasons[f"control_{c}.{name}"] = (
                    f"too little structure near t = {control_times_s[c]:.1f} s: the pairs there see the correction "
                    + (f"only along {', '.join(seen)}" if seen else "along no direction")
                    + f"; known to {100 * value:.2g} cm (above the range noise's {100 * threshold_m:g} cm), bound by "
                    + rigidity)
    return reasons
