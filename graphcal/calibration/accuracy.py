"""Intrinsic parameters the drive determines, but more coarsely than a mapping team needs (config "accuracy").

The weak directions (weak_directions.py) are those the data see less than ten times as well as the nominal model's
prior: held at nominal. Between them and a determined parameter lies one the data do see, to a 1-sigma still above
the accuracy required of it: on a level head over flat ground, a downward fibre's elevation is told from its height
only by the few cars and facades its ring crosses (docs/reference/math.md "Weak directions"), to 0.02-0.04 deg
against a prior of 0.2 deg. Such a parameter is named imprecise (calibration.yaml `imprecise`, beside
`unobservable`), with its sigma and the required one in the reason, and it keeps its fitted value (better than
the nominal, and reported with its sigma).
"""

from __future__ import annotations

import numpy as np

from graphcal.calibration.config import ACCURACY_FIELDS, AccuracySettings
from graphcal.calibration.observability import INTRINSIC_NAMES
from graphcal.recording.intrinsics import DISPLAY_FROM_FILE_UNITS, DISPLAY_NAMES


def imprecise(sigma_intrinsics: np.ndarray, accuracy: AccuracySettings, named: set[str]) -> dict[str, str]:
    """{name: reason} for every estimated intrinsic parameter (a finite 1-sigma in sigma_intrinsics, (n_fibres, 4)
    in file units m, deg, deg, m) not already in named whose 1-sigma exceeds the accuracy required of its kind."""
    required = accuracy.required()
    reasons = {}
    for fibre, column in zip(*np.nonzero(np.isfinite(sigma_intrinsics) & (sigma_intrinsics > required))):
        kind = INTRINSIC_NAMES[column]
        name = f"fibre_{fibre}.{kind}"
        if name in named:
            continue
        scale, unit = DISPLAY_FROM_FILE_UNITS[column], DISPLAY_NAMES[column].rpartition("_")[2]
        reasons[name] = (f"imprecise: determined to {sigma_intrinsics[fibre, column] * scale:.3g} {unit} (1 sigma), "
                         f"coarser than the {required[column] * scale:g} {unit} required (accuracy."
                         f"{ACCURACY_FIELDS[kind]}); its fitted value is kept")
    return reasons
