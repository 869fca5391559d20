"""Parameters the drive determines, but more coarsely than a mapping team needs (config "accuracy").

The weak directions (weak_directions.py) are those the data see less than ten times as well as the nominal model's
prior: held at nominal. Between them and a determined parameter lies one the data do see, to a 1-sigma still above
the accuracy required of it: on a level head over flat ground, a downward fibre's elevation is told from its height
only by the few cars and facades its ring crosses (docs/reference/math.md "Weak directions"), to 0.02-0.04 deg
against a prior of 0.2 deg; over flat ground with few facades a tilted head's pitch trades with the fibres'
elevations. Such a parameter, an intrinsic one or an extrinsic axis, is named imprecise (calibration.yaml
`imprecise`, beside `unobservable`), with its sigma and the required one in the reason, and it keeps its fitted
value, reported with its sigma (the data's estimate, not the nominal's).
"""

from __future__ import annotations

import numpy as np

from graphcal.calibration.config import ACCURACY_FIELDS, AccuracySettings
from graphcal.calibration.observability import EXTRINSIC_NAMES, INTRINSIC_NAMES, Uncertainty, shown


def imprecise(sigmas: Uncertainty, accuracy: AccuracySettings, named: set[str]) -> dict[str, str]:
    """{name: reason} for every estimated intrinsic parameter and extrinsic axis (a finite 1-sigma in sigmas, in
    file units m and deg; the extrinsic None when not estimated) not already in named whose 1-sigma exceeds the
    accuracy required of its kind."""
    coarse = []
    required = accuracy.required()
    for fibre, column in zip(*np.nonzero(np.isfinite(sigmas.intrinsics) & (sigmas.intrinsics > required))):
        coarse.append((f"fibre_{fibre}.{INTRINSIC_NAMES[column]}", sigmas.intrinsics[fibre, column], required[column]))
    if sigmas.extrinsic is not None:
        required = accuracy.required(EXTRINSIC_NAMES)
        for axis in np.nonzero(np.isfinite(sigmas.extrinsic) & (sigmas.extrinsic > required))[0]:
            coarse.append((f"extrinsic.{EXTRINSIC_NAMES[axis]}", sigmas.extrinsic[axis], required[axis]))
    return {name: _reason(name, sigma, need) for name, sigma, need in coarse if name not in named}


def _reason(name: str, sigma: float, required: float) -> str:
    """The plain words for a parameter `name` (file units) determined to `sigma` where `required` is asked."""
    return (f"imprecise: determined to {shown(name, sigma)} (1 sigma), coarser than the {shown(name, required)} "
            f"required (accuracy.{ACCURACY_FIELDS[name.partition('.')[2]]}); its fitted value is kept")
