"""NumPy values in JSON: the `default` of json.dumps for the files graphcal writes (diagnosis.json, checkpoints)."""

from __future__ import annotations

import numpy as np


def plain(value):
    """A NumPy scalar or array as its Python value (json.dumps's default); TypeError for anything else."""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"{type(value)} is not JSON serialisable")
