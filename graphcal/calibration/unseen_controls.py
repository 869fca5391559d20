"""Trajectory corrections the data do not see: stretches of the drive with too little structure.

A control correction moves the returns of the control intervals on each side of its time (eq. 5.1's interpolation);
the pairs among them see it along the normals of the surfaces they lie on. Where the drive crosses an open field, a
featureless road or a gap in the recording, those pairs pin the correction along few directions (the ground's
normal alone: its height) or none: the rigidity prior (E_def, eq. 5.3) and the neighbouring controls hold it there,
and its value is theirs, not the data's. Measured per control by the data's information on it with every other key
held (Problem.control_information), in units of its prior's: a direction with less than WEAK_INFORMATION is unseen,
and a component with more than NAMED_SHARE of its prior variance in such directions is named, as the intrinsics'
weak directions are (weak_directions.py).
"""

from __future__ import annotations

import numpy as np

from graphcal.calibration.observability import CONTROL_NAMES
from graphcal.calibration.weak_directions import NAMED_SHARE, WEAK_INFORMATION


def unseen_controls(information: np.ndarray, control_times_s: np.ndarray) -> dict[str, str]:
    """{control_<c>.<component>: reason} for the components of each control correction its pairs do not see;
    information (C, d, d) from Problem.control_information (d: 6, rotation then translation, or 3), control times [s]
    of the recording's clock."""
    names = CONTROL_NAMES[-information.shape[1]:]
    reasons = {}
    for c, block in enumerate(information):
        values, vectors = np.linalg.eigh(0.5 * (block + block.T))
        weak = vectors[:, values < WEAK_INFORMATION]
        share = np.einsum("ij,ij->i", weak, weak)
        seen = [name for name, s in zip(names, share) if s <= NAMED_SHARE]
        for name in (name for name, s in zip(names, share) if s > NAMED_SHARE):
            reasons[f"control_{c}.{name}"] = (
                f"too little structure near t = {control_times_s[c]:.1f} s: the pairs there see the correction "
                + (f"only along {', '.join(seen)}" if seen else "along no direction")
                + f" (less than {WEAK_INFORMATION:g} times its rigidity prior, eq. 5.3); bound by that prior and the "
                "neighbouring controls")
    return reasons
