"""Trajectory corrections the data do not see: stretches of the drive with too little structure.

A control correction moves the returns of the control intervals on each side of its time (eq. 5.1's interpolation);
the pairs among them see it along the normals of the surfaces they lie on. Where the drive crosses an open field, a
featureless road or a gap in the recording, those pairs pin the correction along few directions (the ground's
normal alone: its height) or none, and E_def holds it there: the seed's prior of no correction (eq. 5.3) or
Monnier's differences, which carry the neighbouring controls' corrections across the stretch. Measured by the
1-sigma the calibration reports for each component (the final fit's marginals: the pairs, E_def's terms under their
loss, the couplings between controls and with the calibration's own keys, widened where the residuals vary more
than their model): a component known no better than the range noise the pairs are whitened by
(weighting.sigma0_m) is named. Under Monnier's differences a stretch of k controls the data do not see is known to
about sigma sqrt(k / 4) in its middle (sigma: E_def's term), so a short gap between two seen streets is not named
and a long one is; a thinly sampled drive whose every control sees a little is not named either, since the chain
pools what its controls see.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from graphcal.calibration.observability import CONTROL_NAMES


def unseen_controls(sigmas: np.ndarray, control_times_s: np.ndarray, deformation: Literal["prior", "monnier"],
                    threshold_m: float) -> dict[str, str]:
    """{control_<c>.<component>: reason} for the components of the control corrections known no better than
    threshold_m [m; a rotation's sigma in rad x 1 m]. sigmas (C, 6): the reported 1-sigmas of each control's
    rotation about world x, y, z [deg] (NaN for translation-only corrections) and translation [m]
    (observability.Uncertainty.controls); control times [s] of the recording's clock; deformation: E_def's form,
    which the reason names as what bounds an unseen component."""
    sigmas = np.asarray(sigmas, dtype=np.float64)
    estimated = ~np.isnan(sigmas).all(axis=0)
    names = [name for name, kept in zip(CONTROL_NAMES, estimated) if kept]
    in_m = np.c_[np.radians(sigmas[:, :3]), sigmas[:, 3:]][:, estimated]
    rigidity = "its prior (eq. 5.3)" if deformation == "prior" else "the neighbouring controls (Monnier's differences)"
    reasons = {}
    for c, sigma in enumerate(in_m):
        unseen = sigma > threshold_m
        seen = [name for name, hidden in zip(names, unseen) if not hidden]
        for name, value in zip(np.array(names)[unseen], sigma[unseen]):
            reasons[f"control_{c}.{name}"] = (
                f"too little structure near t = {control_times_s[c]:.1f} s: the pairs there see the correction "
                + (f"only along {', '.join(seen)}" if seen else "along no direction")
                + f"; known to {100 * value:.2g} cm (above the range noise's {100 * threshold_m:g} cm), bound by "
                + rigidity)
    return reasons
